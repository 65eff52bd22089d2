//! The filter stage: aligned samples in, output records out, with the mode and the
//! coefficients. The only module that touches the compensator API, so wiring the real
//! core means changing the `use` below.

use crate::wire::{Mode, Record};
use magcomp_core::epoch::AlignedSample;

// PLACEHOLDER: switch to `magcomp_core::{Compensator, CompensatorConfig, Output, model::Model}`
// when the core's compensator lands on `main`.
pub use crate::placeholder_comp::N_COEF;
use crate::placeholder_comp::{Compensator, CompensatorConfig, Output, model::Model};

/// State capacity and derivative window of the on-board filter (paper model: 21 states).
pub type BoardCompensator = Compensator<32, 16>;

pub struct Pipeline {
    comp: BoardCompensator,
    mode: Mode,
    /// Sequence number of the next record (= records emitted so far).
    next_seq: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InitError;

impl Pipeline {
    pub fn new(rate_hz: f32) -> Result<Self, InitError> {
        let comp = Compensator::new(Model::paper(), CompensatorConfig::for_rate(rate_hz))
            .map_err(|_| InitError)?;
        Ok(Self {
            comp,
            mode: Mode::Calibrate,
            next_seq: 0,
        })
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

    pub fn coefficients(&self) -> &[f32] {
        self.comp.coefficients()
    }

    pub fn set_coefficients(&mut self, c: &[f32]) -> bool {
        self.comp.set_coefficients(c).is_ok()
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

    /// One sample in; the record of an earlier sample out once the derivative window is full.
    pub fn push(&mut self, s: &AlignedSample) -> Option<Record> {
        self.comp.push(s).map(|o| self.record(o))
    }

    /// End of stream: the records still held, one per call.
    pub fn flush(&mut self) -> Option<Record> {
        self.comp.flush().map(|o| self.record(o))
    }
}
