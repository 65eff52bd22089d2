//! Loops of the per-epoch bookkeeping as free, non-generic functions: compiled once, here,
//! at this crate's opt-level 3 (a method generic over N is compiled in the calling crate, at
//! the firmware's "s"; see filter/ud.rs). Same arithmetic in the same order as the loops they
//! replaced.

/// `Σ c_i·p_i` over the states where `mask_i`.
#[inline(never)]
#[allow(clippy::needless_range_loop)] // arrays indexed together: one bounds check each
pub(super) fn masked_dot(mask: &[bool], c: &[f32], p: &[f32]) -> f32 {
    let n = mask.len();
    let (c, p) = (&c[..n], &p[..n]);
    let mut sum = 0.0f32;
    for i in 0..n {
        if mask[i] {
            sum += c[i] * p[i];
        }
    }
    sum
}

/// `masked_dot` with every entry taken.
#[inline(never)]
#[allow(clippy::needless_range_loop)]
pub(super) fn dot(c: &[f32], p: &[f32]) -> f32 {
    let n = c.len();
    let p = &p[..n];
    let mut sum = 0.0f32;
    for i in 0..n {
        sum += c[i] * p[i];
    }
    sum
}

/// `masked_dot3` with every entry taken.
#[inline(never)]
#[allow(clippy::needless_range_loop)]
pub(super) fn dot3(x: &[f32], s: &[f32], p: &[f32]) -> f32 {
    let n = x.len();
    let (s, p) = (&s[..n], &p[..n]);
    let mut sum = 0.0f32;
    for i in 0..n {
        sum += x[i] * s[i] * p[i];
    }
    sum
}

/// `Σ (x_i·s_i)·p_i` over the states where `mask_i`.
#[inline(never)]
#[allow(clippy::needless_range_loop)]
pub(super) fn masked_dot3(mask: &[bool], x: &[f32], s: &[f32], p: &[f32]) -> f32 {
    let n = mask.len();
    let (x, s, p) = (&x[..n], &s[..n], &p[..n]);
    let mut sum = 0.0f32;
    for i in 0..n {
        if mask[i] {
            sum += x[i] * s[i] * p[i];
        }
    }
    sum
}

/// The interference change regressor: `d_i = (p_i − o_i)·s_i` where `mask_i`, else 0.
#[inline(never)]
#[allow(clippy::needless_range_loop)] // five arrays indexed together: one bounds check each
pub(super) fn change_regressor(mask: &[bool], p: &[f32], o: &[f32], s: &[f32], d: &mut [f32]) {
    let n = d.len();
    let (mask, p, o, s) = (&mask[..n], &p[..n], &o[..n], &s[..n]);
    for i in 0..n {
        d[i] = if mask[i] { (p[i] - o[i]) * s[i] } else { 0.0 };
    }
}

/// `change_regressor` where every entry is an interference term's.
#[inline(never)]
#[allow(clippy::needless_range_loop)]
pub(super) fn change_regressor_all(p: &[f32], o: &[f32], s: &[f32], d: &mut [f32]) {
    let n = d.len();
    let (p, o, s) = (&p[..n], &o[..n], &s[..n]);
    for i in 0..n {
        d[i] = (p[i] - o[i]) * s[i];
    }
}
