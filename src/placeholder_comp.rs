//! PLACEHOLDER for `magcomp_core::Compensator` (being written on `main`), with the announced
//! API so `pipeline.rs` switches by changing one `use`. It is NOT the paper's filter:
//! interference = c0 + c1·ex + c2·ey + c3·ez (e = unit fluxgate vector), compensated =
//! mag − interference, anomaly = compensated − first compensated, innovation = 0.
//! Like the real one it holds `LAG` samples (centred derivative) and emits exactly one
//! output per pushed sample, the held ones on `flush()`.

use magcomp_core::epoch::AlignedSample;
use magcomp_core::{Flags, MagCounts};

pub mod model {
    /// Stand-in for the core's model list (paper: tl16 + field = 21 states).
    pub struct Model;
    impl Model {
        pub const fn paper() -> Self {
            Model
        }
    }
}

#[derive(Clone, Copy, Debug)]
pub struct CompensatorConfig {
    pub rate_hz: f32,
}

impl CompensatorConfig {
    pub const fn for_rate(rate_hz: f32) -> Self {
        Self { rate_hz }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Output {
    pub t_s: f64,
    pub mag: Option<MagCounts>,
    pub interference_nt: f32,
    pub compensated: Option<MagCounts>,
    pub anomaly_nt: f32,
    pub innovation_nt: f32,
    pub innovation_var_nt2: f32,
    pub flags: Flags,
}

/// Deviation coefficients of the Tolles–Lawson model (16 terms).
pub const N_COEF: usize = 16;
const LAG: usize = 2;

pub struct Compensator<const N: usize, const W: usize> {
    held: [Option<AlignedSample>; LAG],
    head: usize,
    coef: [f32; N_COEF],
    survey: bool,
    reference: Option<MagCounts>,
}

impl<const N: usize, const W: usize> Compensator<N, W> {
    pub fn new(_model: model::Model, _cfg: CompensatorConfig) -> Result<Self, ()> {
        Ok(Self {
            held: [None; LAG],
            head: 0,
            coef: [0.0; N_COEF],
            survey: false,
            reference: None,
        })
    }
    pub fn set_survey_mode(&mut self, on: bool) {
        self.survey = on;
    }
    pub fn coefficients(&self) -> &[f32] {
        &self.coef
    }
    pub fn set_coefficients(&mut self, c: &[f32]) -> Result<(), ()> {
        if c.len() != N_COEF || c.iter().any(|v| !v.is_finite()) {
            return Err(());
        }
        self.coef.copy_from_slice(c);
        Ok(())
    }
    pub fn push(&mut self, s: &AlignedSample) -> Option<Output> {
        let out = self.held[self.head].take().map(|h| self.process(&h));
        self.held[self.head] = Some(*s);
        self.head = (self.head + 1) % LAG;
        out
    }
    pub fn flush(&mut self) -> Option<Output> {
        for _ in 0..LAG {
            let h = self.held[self.head].take();
            self.head = (self.head + 1) % LAG;
            if let Some(h) = h {
                return Some(self.process(&h));
            }
        }
        None
    }
    fn process(&mut self, s: &AlignedSample) -> Output {
        let [x, y, z] = s.flux_nt;
        let b = libm::sqrtf(x * x + y * y + z * z);
        let interference_nt = if b.is_finite() && b > 0.0 {
            self.coef[0] + (self.coef[1] * x + self.coef[2] * y + self.coef[3] * z) / b
        } else {
            self.coef[0]
        };
        let compensated = s.mag.map(|m| m.minus_nt(interference_nt));
        if self.reference.is_none() {
            self.reference = compensated;
        }
        let anomaly_nt = match (compensated, self.reference) {
            (Some(c), Some(r)) => c.diff_nt(r),
            _ => f32::NAN,
        };
        let mut flags = s.flags;
        if self.survey {
            flags.set(Flags::SURVEY_MODE);
        }
        Output {
            t_s: s.t_s,
            mag: s.mag,
            interference_nt,
            compensated,
            anomaly_nt,
            innovation_nt: if s.mag.is_some() { 0.0 } else { f32::NAN },
            innovation_var_nt2: f32::NAN,
            flags,
        }
    }
}
