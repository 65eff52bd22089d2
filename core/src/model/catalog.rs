//! The catalogue: every effect a user can name in a model spec, with a one-line physical
//! explanation. Adding an effect = its type in `terms.rs`, one variant in [`AnyTerm`] and
//! one entry in [`CATALOG`] — all in this folder (`docs/adding-an-effect.md`).

use super::terms::*;
use super::Term;
use crate::epoch::Epoch;

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
    pub name: &'static str,
    pub channel: ChannelUse,
    /// One line a geophysicist understands.
    pub effect: &'static str,
    /// Whether the channel's absolute level is meaningless (subtract its first value):
    /// true for a base-station field of ~50 000 nT, false for currents measured from 0.
    pub relative_channel: bool,
}

pub const CATALOG: &[TermInfo] = &[
    TermInfo { name: "permanent", channel: ChannelUse::None, effect: "permanent (hard-iron) magnetisation of the aircraft: K·e", relative_channel: false },
    TermInfo { name: "induced", channel: ChannelUse::None, effect: "magnetisation induced in soft iron by the Earth's field: e_i·e_j·|B|", relative_channel: false },
    TermInfo { name: "eddy", channel: ChannelUse::None, effect: "eddy currents in the airframe driven by manoeuvres: e_i·de_j/dt·|B|", relative_channel: false },
    TermInfo { name: "current", channel: ChannelUse::Required, effect: "field of a current-carrying circuit, proportional to the current channel: I·e", relative_channel: false },
    TermInfo { name: "current_rate", channel: ChannelUse::Required, effect: "inductive coupling of a switching current: dI/dt·e", relative_channel: false },
    TermInfo { name: "lag", channel: ChannelUse::None, effect: "time lag between the scalar sensor and the fluxgate/GPS: the scalar reads B(t−τ); τ is estimated (sub-sample) and the scalar re-aligned by fractional-delay interpolation before the filter (no filter state)", relative_channel: false },
    TermInfo { name: "rate", channel: ChannelUse::None, effect: "eddy currents from flying through field gradients (docs/model.md §4): e_i·e_j·d|B|/dt", relative_channel: false },
    TermInfo { name: "diurnal", channel: ChannelUse::Default("base"), effect: "external (diurnal) field variation recorded by the base station", relative_channel: true },
    TermInfo { name: "induced_high", channel: ChannelUse::None, effect: "higher-order (cubic) induced magnetisation: e_i·e_j·e_k·|B|", relative_channel: false },
    TermInfo { name: "fluxcal", channel: ChannelUse::None, effect: "fluxgate calibration error (bias, scale, non-orthogonality) bending the direction cosines: |B_fluxgate| disagrees with the scalar; fixed by a 9-parameter scalar calibration of the fluxgate (no filter state)", relative_channel: false },
    TermInfo { name: "fluxtemp", channel: ChannelUse::Required, effect: "fluxgate bias/scale drifting with a temperature channel: |B_fluxgate| − B follows (T − T_ref)·(b + s∘B_F); fitted on the fluxgate modulus and corrected before the direction cosines (no filter state)", relative_channel: false },
    TermInfo { name: "fluxmod", channel: ChannelUse::None, effect: "the aircraft's field seen by the fluxgate itself: its modulus minus the scalar's, a second view of the same sources (TL18 spans it through the fluxgate's B_j)", relative_channel: false },
    TermInfo { name: "periodic", channel: ChannelUse::Required, effect: "periodic field of a rotating machine (rpm channel), a vector in the body frame: e_i·cos/sin of its phase", relative_channel: false },
];

/// Looks up an entry by name.
pub fn info(name: &str) -> Option<&'static TermInfo> {
    CATALOG.iter().find(|t| t.name == name)
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
    /// Builds a catalogue term; `channel` is the aux index for terms that use one.
    pub fn make(name: &str, channel: usize) -> Option<Self> {
        Some(match name {
            "permanent" => Self::Permanent(Permanent),
            "induced" => Self::Induced(Induced),
            "eddy" => Self::Eddy(Eddy),
            "current" => Self::Current(Current { channel }),
            "current_rate" => Self::CurrentRate(CurrentRate { channel }),
            "lag" => Self::Lag(Lag),
            "rate" => Self::Rate(Rate),
            "diurnal" => Self::Diurnal(Diurnal { channel }),
            "induced_high" => Self::InducedHigh(InducedHigh),
            "fluxcal" => Self::FluxCal(FluxCal),
            "fluxmod" => Self::FluxMod(FluxMod),
            "periodic" => Self::Periodic(Periodic { channel }),
            "fluxtemp" => Self::FluxTemp(FluxTemp { channel }),
            _ => return None,
        })
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
