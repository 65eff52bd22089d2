//! Model terms: each physical effect is one type implementing [`Term`].
//!
//! A model is the anomaly `field` (5 dynamic states, optional) plus a list of constant-
//! coefficient terms. The paper's model is `permanent + induced + eddy + field` (16 + 5).
//! To add an effect, write one type implementing [`Term`] in `terms.rs` and give it a name
//! in the host's term registry (`docs/adding-an-effect.md`).

pub mod catalog;
pub mod terms;

use crate::epoch::Epoch;
pub use catalog::{AnyTerm, ChannelUse, TermInfo, TermKind, CATALOG};
pub use terms::*;

/// Most regressors a single term may have.
pub const MAX_TERM_STATES: usize = 16;

/// B*, the field strength the induced and eddy terms are normalised by (`|B|/B*`, nT;
/// `docs/model.md` §2), named once for the host's simulator and Tolles–Lawson.
pub const B_STAR_NT: f64 = 50_000.0;

/// One physical effect with constant coefficients: `contribution = Σ θ_i·φ_i(epoch)`.
pub trait Term: Sync {
    /// Base name used in a model spec (`"eddy"`, `"current"`...), for parsing and printing.
    fn name(&self) -> &'static str;
    /// The catalogue term this is, if it is one: what code recognises a term by. A term
    /// outside the catalogue (a diagnostic's, a test's) has none.
    fn kind(&self) -> Option<TermKind> {
        None
    }
    /// Number of coefficients (states) it adds.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Writes its regressors for this epoch into `out[..self.len()]`. Returns false when an
    /// input it needs is missing (the regressors are then zero and the epoch is flagged).
    fn regressors(&self, ep: &Epoch, out: &mut [f32]) -> bool;
    /// Prior 1σ of coefficient `i`, in the coefficient's unit. Also its scale in the filter.
    fn prior_sigma(&self, i: usize) -> f32;
    /// Prior mean of coefficient `i` (0 unless physics fixes it, e.g. a base station sees
    /// the same external field as the aircraft: coefficient 1).
    fn prior_mean(&self, _i: usize) -> f32 {
        0.0
    }
    /// Short label of coefficient `i` (e.g. `"e1*de2"`).
    fn label(&self, i: usize) -> &'static str;
    /// Unit of coefficient `i` (e.g. `"nT"`, `"nT*s"`, `"nT/A"`).
    fn unit(&self, i: usize) -> &'static str;
    /// Aircraft interference (removed by compensation) or part of the environment
    /// (e.g. diurnal variation: estimated, but not interference).
    fn is_interference(&self) -> bool {
        true
    }
    /// Auxiliary channel index this term reads, if any.
    fn channel(&self) -> Option<usize> {
        None
    }
}

/// A model: optional anomaly field plus constant terms. On the board the list is a static
/// array fixed at compile time; on the host it is built at run time from a spec string.
#[derive(Clone, Copy)]
pub struct Model<'a> {
    pub field: bool,
    pub terms: &'a [&'a dyn Term],
}

static PAPER_TERMS: [&dyn Term; 3] = [&Permanent, &Induced, &Eddy];
static WITNESSED_TERMS: [&dyn Term; 4] = [&Permanent, &Induced, &Eddy, &FluxMod];

impl Model<'static> {
    /// The paper's model: `tl16 + field`, 21 states.
    pub fn paper() -> Self {
        Model {
            field: true,
            terms: &PAPER_TERMS,
        }
    }

    /// The paper's model with the fluxgate as a witness of the interference:
    /// `tl16 + field + fluxmod`, 22 states. For an installation whose fluxgate sees the
    /// aircraft's field (the host's post-flight calibration says so and adds `fluxmod`).
    pub fn paper_with_fluxgate_witness() -> Self {
        Model {
            field: true,
            terms: &WITNESSED_TERMS,
        }
    }
}

impl<'a> Model<'a> {
    /// Number of constant coefficients.
    pub fn coefficient_count(&self) -> usize {
        self.terms.iter().map(|t| t.len()).sum()
    }
}
