//! Quality flags carried by every epoch and every output record.
//! A degraded sample is flagged, never dropped.

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Flags(pub u16);

impl Flags {
    /// Fluxgate frame older than the staleness limit (or missing): e, ė held from the last good frame.
    pub const FLUX_STALE: u16 = 1 << 0;
    /// No GPS fix (or GPS stale): speed/position held, field states not propagated with real ds.
    pub const NO_GPS: u16 = 1 << 1;
    /// A parser reported an error since the previous record.
    pub const PARSE_ERROR: u16 = 1 << 2;
    /// The scalar value is missing or not finite: no measurement update this epoch.
    pub const MAG_MISSING: u16 = 1 << 3;
    /// Innovation rejected by the gate (outlier): no measurement update.
    pub const INNOVATION_REJECTED: u16 = 1 << 4;
    /// The filter was (re)initialised at this epoch.
    pub const FILTER_RESET: u16 = 1 << 5;
    /// A tie-point pseudo-measurement was applied at this epoch.
    pub const TIE_POINT: u16 = 1 << 6;
    /// An auxiliary channel used by the model is missing: its regressors are zeroed.
    pub const AUX_MISSING: u16 = 1 << 7;
    /// Survey mode: deviation coefficients frozen (applied, not estimated).
    pub const SURVEY_MODE: u16 = 1 << 8;
    /// The filter has not yet converged (calibration pattern not complete).
    pub const NOT_CONVERGED: u16 = 1 << 9;
    /// Epoch could not be formed with a centred derivative (start of data or gap).
    pub const DERIVATIVE_DEGRADED: u16 = 1 << 10;
    /// A tie-point pseudo-measurement disagreed with the filter beyond its gate and was
    /// refused (e.g. a base channel inconsistent with the scalar).
    pub const TIE_REJECTED: u16 = 1 << 11;
    /// Calibrate mode, converged: the interference's variation within a minute is
    /// determined (the record's bound), but not its change between headings or its level
    /// at this attitude, which the anomaly states share (a pattern flown without revisits:
    /// each heading's legs lie over other ground). The compensated lines then carry a
    /// heading-dependent level for tie-line levelling to remove. Held in survey mode after
    /// an in-flight calibration. Informative: not part of [`Flags::degraded`].
    pub const LEVEL_UNDETERMINED: u16 = 1 << 12;
    /// The scalar reading is suspect: its innovation lies beyond `suspect_sigma` of the
    /// filter's prediction, or, where the filter cannot judge it (no level yet, on the
    /// ground, suspect regressors), it departs from the recent readings (or is the first
    /// one, which nothing can check). A scalar line has no checksum: a corrupted digit is a
    /// different number. Set whether or not the sample was fused (`INNOVATION_REJECTED`
    /// says it was not).
    pub const MAG_SUSPECT: u16 = 1 << 13;
    /// The record is the filter's with the fluxgate as a witness (`fluxmod`), shown because
    /// its own bound is decisively tighter than the paper model's (`compensator::witness`).
    /// Informative: not part of [`Flags::degraded`].
    pub const WITNESS: u16 = 1 << 14;

    pub const fn empty() -> Self {
        Flags(0)
    }
    pub fn set(&mut self, bit: u16) {
        self.0 |= bit;
    }
    pub const fn contains(self, bit: u16) -> bool {
        self.0 & bit != 0
    }
    pub fn union(self, other: Flags) -> Flags {
        Flags(self.0 | other.0)
    }
    /// Any flag that means the compensated value is less trustworthy than normal.
    /// `PARSE_ERROR` alone is not one: it says a line was refused on some port, and what
    /// that costs this sample carries its own flag (`MAG_MISSING`, `FLUX_STALE`,
    /// `DERIVATIVE_DEGRADED`, `NO_GPS`). With 1 % of every port's bytes corrupted it is
    /// on ~80 % of the records, whose values equal the clean run's.
    pub const fn degraded(self) -> bool {
        self.0
            & (Self::FLUX_STALE
                | Self::NO_GPS
                | Self::MAG_MISSING
                | Self::MAG_SUSPECT
                | Self::AUX_MISSING
                | Self::DERIVATIVE_DEGRADED)
            != 0
    }
}
