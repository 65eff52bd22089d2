//! Tie points: the paper's revisited locations (the cloverleaf centre), where a later pass
//! ties the field to the value cloned on the first (model.md §3).

use super::Compensator;
use crate::epoch::Epoch;
use crate::flags::Flags;

pub(super) const TIE_STATE_INIT: TieState = TieState {
    cloned: false,
    inside: false,
    acted: false,
    last_dist_m: 0.0,
    north_m: 0.0,
    east_m: 0.0,
    t_s: 0.0,
    base_nt: 0.0,
    local: None,
    h0_shift_m: 0.0,
    h_m: 0.0,
};

#[derive(Clone, Copy, Debug, Default)]
pub(super) struct TieState {
    cloned: bool,
    inside: bool,
    acted: bool,
    last_dist_m: f32,
    north_m: f32,
    east_m: f32,
    t_s: f64,
    base_nt: f32,
    local: Option<(f32, f32)>,
    /// Cumulative `h0` shift when the clone was taken.
    h0_shift_m: f32,
    /// Height relative to the first `h0` when the clone was taken (m).
    h_m: f32,
}

impl<'a, const N: usize, const W: usize> Compensator<'a, N, W> {
    /// Tie-point logic: on the first pass near a point the field value is cloned; on later
    /// passes `B_h(now) − B_h(then) = 0` is applied with a variance that grows with the
    /// distance between the two passes times the horizontal gradient (model.md §3).
    /// Returns the flag bits to set: `TIE_POINT` when a tie was applied, `TIE_REJECTED`
    /// when one was refused by the gate.
    pub(super) fn tie_points(&mut self, ep: &Epoch) -> u16 {
        let Some(field) = self.field else {
            return 0;
        };
        let mut bits = 0;
        for k in 0..self.n_clone {
            let Some(tp) = self.cfg.tie_points[k] else {
                continue;
            };
            let st = &mut self.ties[k];
            if st.local.is_none() {
                st.local = self.builder.local_position(tp.lat_deg, tp.lon_deg);
            }
            let Some((pn, pe)) = st.local else {
                continue;
            };
            let dn = ep.north_m - pn;
            let de = ep.east_m - pe;
            let dist = libm::sqrtf(dn * dn + de * de);
            if dist > self.cfg.tie_radius_m {
                st.inside = false;
                st.acted = false;
                continue;
            }
            let closest_passed = st.inside && !st.acted && dist > st.last_dist_m;
            st.inside = true;
            st.last_dist_m = dist;
            if !closest_passed {
                continue;
            }
            st.acted = true;
            let clone = self.n_offset + k;
            let bh = self.field_at;
            if !st.cloned {
                st.cloned = true;
                st.north_m = ep.north_m;
                st.east_m = ep.east_m;
                st.t_s = ep.t_s;
                st.base_nt = ep.base_nt;
                st.h0_shift_m = self.h0_shift_m;
                st.h_m = ep.dh_m + self.h0_shift_m;
                self.filter.clone_state(clone, bh);
                continue;
            }
            let sep_n = ep.north_m - st.north_m;
            let sep_e = ep.east_m - st.east_m;
            // The separation of the two passes is three-dimensional: the tie holds the
            // field at one height, and B_z·(h − h0) is only a linearisation of how it
            // changes with height, so a height difference counts like a horizontal one.
            let sep_u = ep.dh_m + self.h0_shift_m - st.h_m;
            let sep_u = if sep_u.is_finite() { sep_u } else { 0.0 };
            let sep_m = libm::sqrtf(sep_n * sep_n + sep_e * sep_e + sep_u * sep_u);
            // Horizontal gradient: the along-track estimate plus 2σ, never below the floor
            // (the cross-track gradient is unobserved; isotropy makes them alike).
            let g_scale = field.scale[1];
            let g_est = libm::fabsf(self.filter.state()[bh + 1] * g_scale)
                + 2.0 * libm::sqrtf(self.filter.variance(bh + 1).max(0.0)) * g_scale;
            let g = g_est.max(self.cfg.tie_gradient_floor_nt_per_m);
            // The field at the point also changed in time (diurnal): measured by the base
            // station when there is one, otherwise allowed for at a quiet-day drift rate.
            // With a `diurnal` term the external variation is already a term of its own and
            // not in B_h: the tie is then B_h(now) = B_h(then), uncertain by the term's ±10 %.
            let (z_tie, r_time) = if ep.base_nt.is_finite() && st.base_nt.is_finite() {
                let d_base = ep.base_nt - st.base_nt;
                if self.models_diurnal {
                    (0.0, 0.03 * 0.03 + (0.1 * d_base) * (0.1 * d_base))
                } else {
                    (d_base, 0.03 * 0.03)
                }
            } else {
                let drift = self.cfg.tie_drift_nt_per_s * (ep.t_s - st.t_s) as f32;
                (0.0, drift * drift)
            };
            let r_tie =
                (sep_m * g) * (sep_m * g) + r_time + 2.0 * self.cfg.noise_nt * self.cfg.noise_nt;
            // Both B_h are fields at their own h0: bring the clone to today's h0 with the
            // current vertical gradient (its uncertainty is carried by the filter).
            let dh0 = self.h0_shift_m - st.h0_shift_m;
            let mut h = [0.0f32; N];
            h[bh] = self.scale[bh];
            h[clone] = -self.scale[clone];
            h[bh + 3] = -dh0 * self.scale[bh + 3];
            let gate = self.cfg.tie_gate_sigma;
            match self.filter.update_gated(&h, z_tie, r_tie, |nu, s| {
                gate > 0.0 && nu * nu > gate * gate * s
            }) {
                Some(Ok(_)) => bits |= Flags::TIE_POINT,
                Some(Err(_)) => bits |= Flags::TIE_REJECTED,
                None => {}
            }
        }
        bits
    }
}
