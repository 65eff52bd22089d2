//! The catalogue: every effect a user can name in a model spec, with a one-line physical
//! explanation. Adding an effect = its type in `terms.rs`, one variant in [`AnyTerm`] and
//! one entry in [`CATALOG`] — all in this folder (`docs/adding-an-effect.md`).

use super::terms::*;
use super::Term;
use crate::epoch::Epoch;

/// Which catalogue term a term is: its typed identity. Code recognises a term by its kind;
/// the name ([`TermKind::name`]) is only for parsing and printing model specs, and is
/// defined here once.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum TermKind {
    Permanent,
    Induced,
    Eddy,
    Current,
    CurrentRate,
    Lag,
    Rate,
    Diurnal,
    InducedHigh,
    FluxCal,
    FluxTemp,
    FluxMod,
    Periodic,
}

impl TermKind {
    /// Every kind, in catalogue order.
    pub const ALL: [TermKind; 13] = [
        TermKind::Permanent,
        TermKind::Induced,
        TermKind::Eddy,
        TermKind::Current,
        TermKind::CurrentRate,
        TermKind::Lag,
        TermKind::Rate,
        TermKind::Diurnal,
        TermKind::InducedHigh,
        TermKind::FluxCal,
        TermKind::FluxTemp,
        TermKind::FluxMod,
        TermKind::Periodic,
    ];

    /// The name a model spec uses for it (`"eddy"`, `"current"`…).
    pub const fn name(self) -> &'static str {
        match self {
            TermKind::Permanent => "permanent",
            TermKind::Induced => "induced",
            TermKind::Eddy => "eddy",
            TermKind::Current => "current",
            TermKind::CurrentRate => "current_rate",
            TermKind::Lag => "lag",
            TermKind::Rate => "rate",
            TermKind::Diurnal => "diurnal",
            TermKind::InducedHigh => "induced_high",
            TermKind::FluxCal => "fluxcal",
            TermKind::FluxTemp => "fluxtemp",
            TermKind::FluxMod => "fluxmod",
            TermKind::Periodic => "periodic",
        }
    }

    /// The kind a model-spec name stands for.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// How a term uses an auxiliary channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelUse {
    /// No channel.
    None,
    /// `name:CHANNEL` is required.
    Required,
    /// `name` alone means this channel.
    Default(&'static str),
}

/// A catalogue entry.
#[derive(Clone, Copy, Debug)]
pub struct TermInfo {
    pub kind: TermKind,
    /// `kind.name()`, kept as a field for readers of the catalogue.
    pub name: &'static str,
    pub channel: ChannelUse,
    /// One line a geophysicist understands.
    pub effect: &'static str,
    /// Whether the channel's absolute level is meaningless (subtract its first value):
    /// true for a base-station field of ~50 000 nT, false for currents measured from 0.
    pub relative_channel: bool,
}

pub const CATALOG: &[TermInfo] = &[
    TermInfo { kind: TermKind::Permanent, name: TermKind::Permanent.name(), channel: ChannelUse::None, effect: "permanent (hard-iron) magnetisation of the aircraft: K·e", relative_channel: false },
    TermInfo { kind: TermKind::Induced, name: TermKind::Induced.name(), channel: ChannelUse::None, effect: "magnetisation induced in soft iron by the Earth's field: e_i·e_j·|B|", relative_channel: false },
    TermInfo { kind: TermKind::Eddy, name: TermKind::Eddy.name(), channel: ChannelUse::None, effect: "eddy currents in the airframe driven by manoeuvres: e_i·de_j/dt·|B|", relative_channel: false },
    TermInfo { kind: TermKind::Current, name: TermKind::Current.name(), channel: ChannelUse::Required, effect: "field of a current-carrying circuit, proportional to the current channel: I·e", relative_channel: false },
    TermInfo { kind: TermKind::CurrentRate, name: TermKind::CurrentRate.name(), channel: ChannelUse::Required, effect: "inductive coupling of a switching current: dI/dt·e", relative_channel: false },
    TermInfo { kind: TermKind::Lag, name: TermKind::Lag.name(), channel: ChannelUse::None, effect: "time lag between the scalar sensor and the fluxgate/GPS: the scalar reads B(t−τ); τ is estimated (sub-sample) and the scalar re-aligned by fractional-delay interpolation before the filter (no filter state)", relative_channel: false },
    TermInfo { kind: TermKind::Rate, name: TermKind::Rate.name(), channel: ChannelUse::None, effect: "eddy currents from flying through field gradients (docs/model.md §4): e_i·e_j·d|B|/dt", relative_channel: false },
    TermInfo { kind: TermKind::Diurnal, name: TermKind::Diurnal.name(), channel: ChannelUse::Default("base"), effect: "external (diurnal) field variation recorded by the base station", relative_channel: true },
    TermInfo { kind: TermKind::InducedHigh, name: TermKind::InducedHigh.name(), channel: ChannelUse::None, effect: "higher-order (cubic) induced magnetisation: e_i·e_j·e_k·|B|", relative_channel: false },
    TermInfo { kind: TermKind::FluxCal, name: TermKind::FluxCal.name(), channel: ChannelUse::None, effect: "fluxgate calibration error (bias, scale, non-orthogonality) bending the direction cosines: |B_fluxgate| disagrees with the scalar; fixed by a 9-parameter scalar calibration of the fluxgate (no filter state)", relative_channel: false },
    TermInfo { kind: TermKind::FluxTemp, name: TermKind::FluxTemp.name(), channel: ChannelUse::Required, effect: "fluxgate bias/scale drifting with a temperature channel: |B_fluxgate| − B follows (T − T_ref)·(b + s∘B_F); fitted on the fluxgate modulus and corrected before the direction cosines (no filter state)", relative_channel: false },
    TermInfo { kind: TermKind::FluxMod, name: TermKind::FluxMod.name(), channel: ChannelUse::None, effect: "the aircraft's field seen by the fluxgate itself: its modulus minus the scalar's, a second view of the same sources (TL18 spans it through the fluxgate's B_j)", relative_channel: false },
    TermInfo { kind: TermKind::Periodic, name: TermKind::Periodic.name(), channel: ChannelUse::Required, effect: "periodic field of a rotating machine (rpm channel), a vector in the body frame: e_i·cos/sin of its phase", relative_channel: false },
];

/// Looks up an entry by name.
pub fn info(name: &str) -> Option<&'static TermInfo> {
    TermKind::from_name(name).map(info_of)
}

/// The entry of a kind.
pub fn info_of(kind: TermKind) -> &'static TermInfo {
    CATALOG
        .iter()
        .find(|t| t.kind == kind)
        .expect("every kind has a catalogue entry")
}

/// Any catalogue term by value: lets the board keep its model in a static array and the
/// host build one at run time, without allocation.
#[derive(Clone, Copy)]
pub enum AnyTerm {
    Permanent(Permanent),
    Induced(Induced),
    Eddy(Eddy),
    Current(Current),
    CurrentRate(CurrentRate),
    Lag(Lag),
    Rate(Rate),
    Diurnal(Diurnal),
    InducedHigh(InducedHigh),
    FluxCal(FluxCal),
    FluxMod(FluxMod),
    Periodic(Periodic),
    FluxTemp(FluxTemp),
}

impl AnyTerm {
    /// Builds a catalogue term by name; `channel` is the aux index for terms that use one.
    pub fn make(name: &str, channel: usize) -> Option<Self> {
        TermKind::from_name(name).map(|k| Self::of(k, channel))
    }

    /// Builds a catalogue term; `channel` is the aux index for terms that use one.
    pub fn of(kind: TermKind, channel: usize) -> Self {
        match kind {
            TermKind::Permanent => Self::Permanent(Permanent),
            TermKind::Induced => Self::Induced(Induced),
            TermKind::Eddy => Self::Eddy(Eddy),
            TermKind::Current => Self::Current(Current { channel }),
            TermKind::CurrentRate => Self::CurrentRate(CurrentRate { channel }),
            TermKind::Lag => Self::Lag(Lag),
            TermKind::Rate => Self::Rate(Rate),
            TermKind::Diurnal => Self::Diurnal(Diurnal { channel }),
            TermKind::InducedHigh => Self::InducedHigh(InducedHigh),
            TermKind::FluxCal => Self::FluxCal(FluxCal),
            TermKind::FluxMod => Self::FluxMod(FluxMod),
            TermKind::Periodic => Self::Periodic(Periodic { channel }),
            TermKind::FluxTemp => Self::FluxTemp(FluxTemp { channel }),
        }
    }

    fn inner(&self) -> &dyn Term {
        match self {
            Self::Permanent(t) => t,
            Self::Induced(t) => t,
            Self::Eddy(t) => t,
            Self::Current(t) => t,
            Self::CurrentRate(t) => t,
            Self::Lag(t) => t,
            Self::Rate(t) => t,
            Self::Diurnal(t) => t,
            Self::InducedHigh(t) => t,
            Self::FluxCal(t) => t,
            Self::FluxMod(t) => t,
            Self::Periodic(t) => t,
            Self::FluxTemp(t) => t,
        }
    }
}

impl Term for AnyTerm {
    fn name(&self) -> &'static str {
        self.inner().name()
    }
    fn kind(&self) -> Option<TermKind> {
        self.inner().kind()
    }
    fn len(&self) -> usize {
        self.inner().len()
    }
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool {
        self.inner().regressors(ep, out)
    }
    fn prior_sigma(&self, i: usize) -> f32 {
        self.inner().prior_sigma(i)
    }
    fn prior_mean(&self, i: usize) -> f32 {
        self.inner().prior_mean(i)
    }
    fn label(&self, i: usize) -> &'static str {
        self.inner().label(i)
    }
    fn unit(&self, i: usize) -> &'static str {
        self.inner().unit(i)
    }
    fn is_interference(&self) -> bool {
        self.inner().is_interference()
    }
    fn channel(&self) -> Option<usize> {
        self.inner().channel()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_has_its_entry_in_order_and_builds_a_term_of_that_kind() {
        assert_eq!(CATALOG.len(), TermKind::ALL.len());
        for (ti, k) in CATALOG.iter().zip(TermKind::ALL) {
            assert_eq!(ti.kind, k);
            assert_eq!(ti.name, k.name());
            assert_eq!(TermKind::from_name(k.name()), Some(k));
            let t = AnyTerm::of(k, 0);
            assert_eq!(t.kind(), Some(k));
            assert_eq!(t.name(), k.name());
        }
        assert_eq!(TermKind::from_name("tl16"), None);
        assert_eq!(Offset.kind(), None);
    }
}
