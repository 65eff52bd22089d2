//! The fluxgate's delay line: the board's side of `lag` (issue 12 item 1).
//!
//! The scalar sensor reports at t what it measured at t − τ. The host re-aligns the scalar
//! (`mag(t) ← mag(t + τ)`), which needs the scalar's future; the board delays the other
//! side instead: each scalar sample stamped t is paired with the fluxgate interpolated at
//! t − τ (linear, between the two frames that bracket it, as the aligner does at τ = 0).
//! The record keeps the scalar's time stamp and sequence number: one record per scalar
//! sample, as always.
//!
//! Sized for the worst case the board supports: τ up to 0.5 s at a fluxgate of
//! [`LAG_TOP_FLUX_HZ`] (500 frames, plus the two bracketing ones), so [`LAG_FRAMES`] = 512,
//! which holds [`MAX_LAG_S`] = 0.51 s at that rate.
//! Stamps are held as their low 32 bits relative to the newest frame's full stamp (16 bytes a
//! frame, 8 KiB in all); frames further than [`MAX_SPAN_US`] behind the newest are dropped,
//! so the 32-bit differences never wrap. All-zero when new, so a board's `static` of it sits
//! in `.bss` and costs no flash.

/// Frames held: 0.5 s × 1 kHz + 2 bracketing frames, rounded up to a power of two.
pub const LAG_FRAMES: usize = 512;
/// Fluxgate rate (Hz) at which the delay line still holds [`MAX_LAG_S`]: the board's top rate.
pub const LAG_TOP_FLUX_HZ: f32 = 1000.0;
/// Longest delay the board applies (s): what the line holds at [`LAG_TOP_FLUX_HZ`], 0.51 s,
/// so a true 0.5 s lag still fits with its estimate's error (τ̂ = 0.5038 s on a simulated
/// flight with τ = 0.5 s at 10 Hz).
pub const MAX_LAG_S: f32 = (LAG_FRAMES - 2) as f32 / LAG_TOP_FLUX_HZ;
/// Widest stamp span kept (µs, ~36 min): far beyond any staleness limit.
pub const MAX_SPAN_US: u64 = 1 << 31;

/// Why a delay is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LagError {
    /// Not finite, negative or above [`MAX_LAG_S`].
    OutOfRange,
    /// More frames at the nominal fluxgate rate than the line holds.
    BeyondLine,
    /// A delay > 0 with no delay line attached.
    NoLine,
}

/// Whether `lag_s` fits the line at a nominal fluxgate rate of `flux_hz`.
pub fn check_lag(lag_s: f32, flux_hz: f64) -> Result<(), LagError> {
    if !(0.0..=MAX_LAG_S).contains(&lag_s) {
        return Err(LagError::OutOfRange);
    }
    // Frames between t − τ and t, plus the two that bracket t − τ.
    if f64::from(lag_s) * flux_hz + 2.0 > LAG_FRAMES as f64 {
        return Err(LagError::BeyondLine);
    }
    Ok(())
}

/// The last [`LAG_FRAMES`] fluxgate frames, oldest first, as a ring.
#[derive(Clone, Debug)]
pub struct LagLine {
    /// Low 32 bits of each frame's stamp (µs).
    stamps: [u32; LAG_FRAMES],
    flux_nt: [[f32; 3]; LAG_FRAMES],
    /// Ring index of the oldest frame.
    start: usize,
    len: usize,
    /// Full stamp of the newest frame.
    newest_us: u64,
}

impl Default for LagLine {
    fn default() -> Self {
        Self::new()
    }
}

impl LagLine {
    pub const fn new() -> Self {
        Self {
            stamps: [0; LAG_FRAMES],
            flux_nt: [[0.0; 3]; LAG_FRAMES],
            start: 0,
            len: 0,
            newest_us: 0,
        }
    }

    pub fn clear(&mut self) {
        self.start = 0;
        self.len = 0;
        self.newest_us = 0;
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// A fluxgate frame (body frame, nT) stamped `t_us`. A stamp earlier than the newest
    /// (restart, new replay) starts the line afresh.
    pub fn push(&mut self, t_us: u64, flux_nt: [f32; 3]) {
        if self.len > 0 && t_us < self.newest_us {
            self.clear();
        }
        if self.len == LAG_FRAMES {
            self.pop_oldest();
        }
        let i = (self.start + self.len) % LAG_FRAMES;
        self.stamps[i] = t_us as u32;
        self.flux_nt[i] = flux_nt;
        self.len += 1;
        self.newest_us = t_us;
        while self.len > 1 && t_us - self.get(0).0 >= MAX_SPAN_US {
            self.pop_oldest();
        }
    }

    fn pop_oldest(&mut self) {
        self.start = (self.start + 1) % LAG_FRAMES;
        self.len -= 1;
    }

    /// Frame `i` (0 = oldest; `i < len`): full stamp (µs) and value.
    pub fn get(&self, i: usize) -> (u64, [f32; 3]) {
        let j = (self.start + i) % LAG_FRAMES;
        let back = (self.newest_us as u32).wrapping_sub(self.stamps[j]);
        (
            self.newest_us.saturating_sub(u64::from(back)),
            self.flux_nt[j],
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_keeps_the_newest_frames_with_full_stamps() {
        let mut l = LagLine::new();
        // Stamps beyond 2^32 µs: the low 32 bits alone would wrap.
        let t0 = (1u64 << 32) - 3_000;
        for k in 0..(LAG_FRAMES as u64 + 100) {
            l.push(t0 + 1_000 * k, [k as f32, 0.0, 0.0]);
        }
        assert_eq!(l.len(), LAG_FRAMES);
        let (t, v) = l.get(0);
        assert_eq!(t, t0 + 1_000 * 100);
        assert_eq!(v[0], 100.0);
        let (t, v) = l.get(LAG_FRAMES - 1);
        assert_eq!(t, t0 + 1_000 * (LAG_FRAMES as u64 + 99));
        assert_eq!(v[0], (LAG_FRAMES + 99) as f32);
        // Back in time: afresh.
        l.push(5, [1.0; 3]);
        assert_eq!((l.len(), l.get(0).0), (1, 5));
        // A frame far after the others drops them (span limit).
        l.push(5 + MAX_SPAN_US, [2.0; 3]);
        assert_eq!((l.len(), l.get(0).0), (1, 5 + MAX_SPAN_US));
    }

    #[test]
    fn lag_bounds() {
        assert_eq!(check_lag(0.0, 10.0), Ok(()));
        assert_eq!(check_lag(0.5, 1000.0), Ok(()));
        assert_eq!(check_lag(MAX_LAG_S, 1000.0), Ok(()));
        assert_eq!(check_lag(0.5101, 10.0), Err(LagError::OutOfRange));
        assert_eq!(check_lag(-0.01, 10.0), Err(LagError::OutOfRange));
        assert_eq!(check_lag(f32::NAN, 10.0), Err(LagError::OutOfRange));
        assert_eq!(check_lag(0.5, 1100.0), Err(LagError::BeyondLine));
    }
}
