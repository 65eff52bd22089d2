//! The filter stage, pure (no embassy) so the host replay and hil-tests run the same code:
//! aligned samples in, output records out, plus the mode and the coefficients.

use magcomp_core::compensator::CompensatorError;
use magcomp_core::epoch::AlignedSample;
use magcomp_core::model::Model;
use magcomp_core::protocol::command::{Mode, model_hash};
use magcomp_core::protocol::record::Record;
use magcomp_core::{Compensator, CompensatorConfig, Output};

/// The model compiled into the board (the paper's: 16 TL coefficients + 5 field states).
pub const MODEL_SPEC: &[u8] = b"tl16+field";
/// Coefficients of `MODEL_SPEC` (the index bound of GETCOEF/SETCOEF).
pub const N_COEF: usize = 16;
/// State capacity and derivative-window capacity of the on-board filter.
pub const STATE_CAPACITY: usize = 32;
pub const WINDOW: usize = 16;

pub type BoardCompensator = Compensator<'static, STATE_CAPACITY, WINDOW>;

/// Model id stored in the coefficient blob.
pub fn model_id() -> u32 {
    model_hash(MODEL_SPEC)
}

pub struct Filter {
    comp: BoardCompensator,
    mode: Mode,
    rate_hz: f32,
    /// Sequence number of the next record (= records emitted so far).
    next_seq: u32,
}

fn config(rate_hz: f32) -> CompensatorConfig {
    let mut cfg = CompensatorConfig::for_rate(rate_hz);
    // the ring holds 2·half_width + 1 samples: above ~150 Hz the derivative spans fewer
    // than ±0.05 s rather than the filter refusing to start
    cfg.epoch.half_width = cfg.epoch.half_width.min((WINDOW - 1) / 2);
    cfg
}

impl Filter {
    pub fn new(rate_hz: f32) -> Result<Self, CompensatorError> {
        let comp = Compensator::new(Model::paper(), config(rate_hz))?;
        Ok(Self {
            comp,
            mode: Mode::Cal,
            rate_hz,
            next_seq: 0,
        })
    }

    /// Restarts the filter (priors, derivative window); sequence numbers keep counting.
    /// The caller flushes first so no sample loses its record.
    pub fn reset(&mut self) -> Result<(), CompensatorError> {
        self.comp = Compensator::new(Model::paper(), config(self.rate_hz))?;
        self.mode = Mode::Cal;
        Ok(())
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    pub fn set_mode(&mut self, mode: Mode) {
        self.mode = mode;
        self.comp.set_survey_mode(mode == Mode::Survey);
    }

    pub fn records(&self) -> u32 {
        self.next_seq
    }

    pub fn coefficients(&self) -> [f32; N_COEF] {
        let mut c = [0f32; N_COEF];
        self.comp.coefficients(&mut c);
        c
    }

    /// Loads coefficients; the compensator then applies them (survey mode).
    pub fn set_coefficients(&mut self, c: &[f32]) -> Result<(), CompensatorError> {
        self.comp.set_coefficients(c)?;
        self.mode = Mode::Survey;
        Ok(())
    }

    fn record(&mut self, o: Output) -> Record {
        let seq = self.next_seq;
        self.next_seq = self.next_seq.wrapping_add(1);
        Record {
            seq,
            t_s: o.t_s,
            mag: o.mag,
            interference_nt: o.interference_nt,
            compensated: o.compensated,
            anomaly_nt: o.anomaly_nt,
            innovation_nt: o.innovation_nt,
            flags: o.flags,
        }
    }

    /// One sample in; the record of the sample `half_width` back out.
    pub fn push(&mut self, s: &AlignedSample) -> Option<Record> {
        self.comp.push(s).map(|o| self.record(o))
    }

    /// End of stream: the records still held, one per call.
    pub fn flush(&mut self) -> Option<Record> {
        self.comp.flush().map(|o| self.record(o))
    }
}
