//! The `lag` candidate's detector. `lag` itself is a delay applied to the scalar before the
//! filter (`corrections::lag`), so it has no regressors; to test whether a flight holds one,
//! the diagnosis uses its first-order form, `B(t−τ) ≈ B(t) − τ·dB/dt`: the time derivatives
//! of what the scalar sees, `d|B|/dt` and those of the permanent and induced regressors
//! (`ė_i`, `d(e_i e_j)/dt·|B|/B*`), 9 in all. Enough to detect and rank the effect; the
//! compensation then uses the exact delay.

use super::ExtraTerm;
use magcomp_core::epoch::Epoch;
use magcomp_core::model::Term;

pub struct LagTaylor;

impl Term for LagTaylor {
    fn name(&self) -> &'static str {
        "lag"
    }
    fn len(&self) -> usize {
        9
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let e = &ep.e;
        let d = &ep.e_dot_per_s;
        let k = ep.field_ratio;
        out[0] = ep.dmag_dt_nt_per_s;
        out[1] = d[0];
        out[2] = d[1];
        out[3] = d[2];
        out[4] = 2.0 * e[0] * d[0] * k;
        out[5] = 2.0 * e[1] * d[1] * k;
        out[6] = (e[0] * d[1] + e[1] * d[0]) * k;
        out[7] = (e[0] * d[2] + e[2] * d[0]) * k;
        out[8] = (e[1] * d[2] + e[2] * d[1]) * k;
        true
    }
    fn prior_sigma(&self, i: usize) -> f32 {
        if i == 0 {
            1.0
        } else {
            30.0
        }
    }
    fn label(&self, i: usize) -> &'static str {
        [
            "dB", "de1", "de2", "de3", "d(e1e1)", "d(e2e2)", "d(e1e2)", "d(e1e3)", "d(e2e3)",
        ][i]
    }
    fn unit(&self, i: usize) -> &'static str {
        if i == 0 {
            "s"
        } else {
            "nT*s"
        }
    }
}

pub const LAG_DETECTOR: ExtraTerm = ExtraTerm {
    name: "lag",
    effect: "time lag between the scalar sensor and the fluxgate/GPS (detected by its first-order form −τ·d/dt; adding `lag` estimates τ and re-aligns the scalar)",
    needs_channel: false,
    make: |_| Box::new(LagTaylor),
};
