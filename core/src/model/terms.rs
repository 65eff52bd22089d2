//! The catalogue of physical effects. Regressors follow model.md §2 (eq. 10 of the paper);
//! the extra effects follow model.md §4 and the diagnosis catalogue.

use super::catalog::TermKind;
use super::{Term, MAX_TERM_STATES};
use crate::epoch::Epoch;

/// Permanent magnetisation: `K·e` (3, nT).
#[derive(Clone, Copy, Debug)]
pub struct Permanent;
/// Induced magnetisation: `e_i e_j·|B|/B*` without `e3²` (5, nT).
#[derive(Clone, Copy, Debug)]
pub struct Induced;
/// Eddy currents: `e_i ė_j·|B|/B*` without `e3ė3` (8, nT·s).
#[derive(Clone, Copy, Debug)]
pub struct Eddy;
/// A current-carrying circuit: `I·e_i` (3, nT/A) for auxiliary channel `channel`.
#[derive(Clone, Copy, Debug)]
pub struct Current {
    pub channel: usize,
}
/// Inductive coupling of a changing current: `dI/dt·e_i` (3, nT·s/A).
#[derive(Clone, Copy, Debug)]
pub struct CurrentRate {
    pub channel: usize,
}
/// Time lag between the scalar sensor and the fluxgate/GPS: a scalar sample tagged τ late
/// reads `B(t−τ)`. It is a delay, not a regressor: a first-order term `−τ·dB/dt` leaves
/// (ωτ)²-sized residuals at manoeuvre frequencies. Naming it asks for τ to be estimated
/// and the scalar re-aligned by fractional-delay interpolation before the filter (host:
/// `preprocess::lag`). It adds no filter state.
#[derive(Clone, Copy, Debug)]
pub struct Lag;
/// The ε⁶ eddy term from flying through gradients: `e_i e_j·d|B|/dt` (5, s), model.md §4.
#[derive(Clone, Copy, Debug)]
pub struct Rate;
/// External (diurnal) variation recorded by a base station: `base − base₀` (1, nT/nT).
#[derive(Clone, Copy, Debug)]
pub struct Diurnal {
    pub channel: usize,
}
/// Higher-order induced magnetisation: the 7 independent cubic monomials of e (nT).
#[derive(Clone, Copy, Debug)]
pub struct InducedHigh;
/// Fluxgate calibration (bias, scale, non-orthogonality). A miscalibrated fluxgate bends
/// the direction cosines every TL regressor is built from, and a TL fit made with that
/// fluxgate absorbs the bend's low-order part, so the error hides from the scalar residual.
/// What exposes it is the fluxgate's own modulus against the scalar: the fix is the classic
/// 9-parameter scalar calibration of the fluxgate, fitted on the flight (host) and applied
/// to the fluxgate before `e` is formed ([`crate::protocol::fluxgate::FluxCalibration`] on the
/// board). It adds no filter state: naming it in a model asks for that calibration.
#[derive(Clone, Copy, Debug)]
pub struct FluxCal;
/// Fluxgate bias and scale that follow a temperature channel: `B = B_F + (T − T_ref)·(b +
/// s∘B_F)` (b in nT/°C, s in 1/°C per axis). Like [`FluxCal`] it bends the direction cosines
/// and shows on the fluxgate's modulus against the scalar, not in the scalar residual; the
/// host fits it there and corrects the fluxgate before `e` is formed. No filter state.
#[derive(Clone, Copy, Debug)]
pub struct FluxTemp {
    pub channel: usize,
}
/// Periodic interference locked to a rotation channel (rpm): an engine or propeller field is
/// a vector in the body frame, so the scalar sees its projection on the field direction:
/// `e_i·cos/sin` of the 1st and 2nd harmonic of the rotation phase (12, nT).
#[derive(Clone, Copy, Debug)]
pub struct Periodic {
    pub channel: usize,
}
/// The aircraft's field at the fluxgate: `|B_fluxgate| − |B_scalar|` (1, nT/nT). The paper
/// takes the fluxgate for a direction sensor only, but a fluxgate inside the airframe also
/// reads the aircraft's own field, from the same sources as the scalar's interference; its
/// modulus excess over the scalar is a second, independent view of that interference. The
/// Earth's field (anomaly, diurnal) cancels in the difference, so the term cannot bend the
/// anomaly. Classic TL18 spans this direction implicitly (its `e_i·B_j` columns carry the
/// fluxgate's modulus); on the real SGL calibration boxes it took box 1 → box 2 from 3.4 to
/// 1.6–3.0 nT (mag_4) in the manoeuvre band.
#[derive(Clone, Copy, Debug)]
pub struct FluxMod;
/// An unknown constant offset: used when the model has no field states to absorb it.
#[derive(Clone, Copy, Debug)]
pub struct Offset;

impl Term for Permanent {
    fn name(&self) -> &'static str {
        TermKind::Permanent.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Permanent)
    }
    fn len(&self) -> usize {
        3
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        out[..3].copy_from_slice(&ep.e);
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        200.0
    }
    fn label(&self, i: usize) -> &'static str {
        ["e1", "e2", "e3"][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT"
    }
}

fn induced_monomials(e: &[f32; 3]) -> [f32; 5] {
    [
        e[0] * e[0],
        e[1] * e[1],
        e[0] * e[1],
        e[0] * e[2],
        e[1] * e[2],
    ]
}

impl Term for Induced {
    fn name(&self) -> &'static str {
        TermKind::Induced.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Induced)
    }
    fn len(&self) -> usize {
        5
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let m = induced_monomials(&ep.e);
        for (o, v) in out.iter_mut().zip(m) {
            *o = v * ep.field_ratio;
        }
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        200.0
    }
    fn label(&self, i: usize) -> &'static str {
        ["e1*e1", "e2*e2", "e1*e2", "e1*e3", "e2*e3"][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT"
    }
}

impl Term for Eddy {
    fn name(&self) -> &'static str {
        TermKind::Eddy.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Eddy)
    }
    fn len(&self) -> usize {
        8
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        // e_i·ė_j for (i, j) = (0,0) (1,1) (0,1) (1,0) (0,2) (2,0) (1,2) (2,1), the paper's
        // order, written out: a loop over an index table cost ~19 instructions a regressor
        // on the M4, and this runs 13 times an epoch at every envelope evaluation
        let ([a, b, c], [da, db, dc]) = (ep.e, ep.e_dot_per_s);
        let m = [
            a * da,
            b * db,
            a * db,
            b * da,
            a * dc,
            c * da,
            b * dc,
            c * db,
        ];
        for (o, v) in out.iter_mut().zip(m) {
            *o = v * ep.field_ratio;
        }
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        30.0
    }
    fn label(&self, i: usize) -> &'static str {
        [
            "e1*de1", "e2*de2", "e1*de2", "e2*de1", "e1*de3", "e3*de1", "e2*de3", "e3*de2",
        ][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT*s"
    }
}

fn aux_value(ep: &Epoch, channel: usize) -> Option<f32> {
    ep.aux.get(channel).copied().filter(|v| v.is_finite())
}

fn aux_rate(ep: &Epoch, channel: usize) -> Option<f32> {
    ep.aux_dot.get(channel).copied().filter(|v| v.is_finite())
}

fn fill_scaled_e(out: &mut [f32], e: &[f32; 3], k: Option<f32>) -> bool {
    match k {
        Some(k) => {
            for (o, ei) in out.iter_mut().zip(e) {
                *o = k * ei;
            }
            true
        }
        None => {
            out[..3].fill(0.0);
            false
        }
    }
}

impl Term for Current {
    fn name(&self) -> &'static str {
        TermKind::Current.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Current)
    }
    fn len(&self) -> usize {
        3
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        fill_scaled_e(out, &ep.e, aux_value(ep, self.channel))
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        10.0
    }
    fn label(&self, i: usize) -> &'static str {
        ["I*e1", "I*e2", "I*e3"][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT/unit"
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}

impl Term for CurrentRate {
    fn name(&self) -> &'static str {
        TermKind::CurrentRate.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::CurrentRate)
    }
    fn len(&self) -> usize {
        3
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        fill_scaled_e(out, &ep.e, aux_rate(ep, self.channel))
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        10.0
    }
    fn label(&self, i: usize) -> &'static str {
        ["dI*e1", "dI*e2", "dI*e3"][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT*s/unit"
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}

impl Term for Lag {
    fn name(&self) -> &'static str {
        TermKind::Lag.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Lag)
    }
    fn len(&self) -> usize {
        0
    }
    fn regressors(&self, _: &Epoch, _: &mut [f32]) -> bool {
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        1.0
    }
    fn label(&self, _: usize) -> &'static str {
        ""
    }
    fn unit(&self, _: usize) -> &'static str {
        ""
    }
}

impl Term for FluxTemp {
    fn name(&self) -> &'static str {
        TermKind::FluxTemp.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::FluxTemp)
    }
    fn len(&self) -> usize {
        0
    }
    fn regressors(&self, _: &Epoch, _: &mut [f32]) -> bool {
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        1.0
    }
    fn label(&self, _: usize) -> &'static str {
        ""
    }
    fn unit(&self, _: usize) -> &'static str {
        ""
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}

impl Term for Rate {
    fn name(&self) -> &'static str {
        TermKind::Rate.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Rate)
    }
    fn len(&self) -> usize {
        5
    }
    // The 5 induced monomials only: with e3² (or a constant) the set would span d|B|/dt
    // itself (Σe_i² = 1), which is a lag, not an eddy effect of the gradient.
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let r = ep.dmag_dt_nt_per_s;
        let m = induced_monomials(&ep.e);
        for (o, v) in out[..5].iter_mut().zip(m) {
            *o = r * v;
        }
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        0.1
    }
    fn label(&self, i: usize) -> &'static str {
        ["e1*e1*dB", "e2*e2*dB", "e1*e2*dB", "e1*e3*dB", "e2*e3*dB"][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "s"
    }
}

impl Term for Diurnal {
    fn name(&self) -> &'static str {
        TermKind::Diurnal.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Diurnal)
    }
    fn len(&self) -> usize {
        1
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        match aux_value(ep, self.channel) {
            Some(v) => {
                out[0] = v;
                true
            }
            None => {
                out[0] = 0.0;
                false
            }
        }
    }
    // The base station records the same external variation the aircraft flies through
    // (it is uniform over tens of km): coefficient 1, allowed ±0.1 for gain differences.
    // Left free, the field states take most of the slow variation and β drifts to ~0.1.
    fn prior_sigma(&self, _: usize) -> f32 {
        0.1
    }
    fn prior_mean(&self, _: usize) -> f32 {
        1.0
    }
    fn label(&self, _: usize) -> &'static str {
        "base"
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT/nT"
    }
    fn is_interference(&self) -> bool {
        false
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}

impl Term for InducedHigh {
    fn name(&self) -> &'static str {
        TermKind::InducedHigh.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::InducedHigh)
    }
    fn len(&self) -> usize {
        7
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let [a, b, c] = ep.e;
        let k = ep.field_ratio;
        let m = [
            a * a * a,
            b * b * b,
            a * a * b,
            a * b * b,
            a * a * c,
            b * b * c,
            a * b * c,
        ];
        for (o, v) in out.iter_mut().zip(m) {
            *o = v * k;
        }
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        50.0
    }
    fn label(&self, i: usize) -> &'static str {
        [
            "e1^3", "e2^3", "e1^2e2", "e1e2^2", "e1^2e3", "e2^2e3", "e1e2e3",
        ][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT"
    }
}

impl Term for FluxMod {
    fn name(&self) -> &'static str {
        TermKind::FluxMod.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::FluxMod)
    }
    fn len(&self) -> usize {
        1
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        let ok = ep.flux_excess_nt.is_finite();
        out[0] = if ok { ep.flux_excess_nt } else { 0.0 };
        ok
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        1.0
    }
    fn label(&self, _: usize) -> &'static str {
        "|F|-|B|"
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT/nT"
    }
}

impl Term for FluxCal {
    fn name(&self) -> &'static str {
        TermKind::FluxCal.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::FluxCal)
    }
    fn len(&self) -> usize {
        0
    }
    fn regressors(&self, _: &Epoch, _: &mut [f32]) -> bool {
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        1.0
    }
    fn label(&self, _: usize) -> &'static str {
        ""
    }
    fn unit(&self, _: usize) -> &'static str {
        ""
    }
}

impl Term for Periodic {
    fn name(&self) -> &'static str {
        TermKind::Periodic.name()
    }
    fn kind(&self) -> Option<TermKind> {
        Some(TermKind::Periodic)
    }
    fn len(&self) -> usize {
        12
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        if aux_value(ep, self.channel).is_none() {
            out[..12].fill(0.0);
            return false;
        }
        let phase = 2.0 * core::f32::consts::PI * ep.aux_cycles[self.channel];
        let (s1, c1) = libm::sincosf(phase);
        let (s2, c2) = libm::sincosf(2.0 * phase);
        for (k, w) in [c1, s1, c2, s2].into_iter().enumerate() {
            for i in 0..3 {
                out[3 * k + i] = w * ep.e[i];
            }
        }
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        10.0
    }
    fn label(&self, i: usize) -> &'static str {
        [
            "cos1*e1", "cos1*e2", "cos1*e3", "sin1*e1", "sin1*e2", "sin1*e3", "cos2*e1", "cos2*e2",
            "cos2*e3", "sin2*e1", "sin2*e2", "sin2*e3",
        ][i]
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT"
    }
    fn channel(&self) -> Option<usize> {
        Some(self.channel)
    }
}

impl Term for Offset {
    fn name(&self) -> &'static str {
        "offset"
    }
    fn len(&self) -> usize {
        1
    }
    fn regressors(&self, _: &Epoch, out: &mut [f32]) -> bool {
        out[0] = 1.0;
        true
    }
    fn prior_sigma(&self, _: usize) -> f32 {
        1000.0
    }
    fn label(&self, _: usize) -> &'static str {
        "1"
    }
    fn unit(&self, _: usize) -> &'static str {
        "nT"
    }
    fn is_interference(&self) -> bool {
        false
    }
}

const _: () = assert!(MAX_TERM_STATES >= 8);
