//! Model specs as users type them: `+`-joined term names, e.g. `tl16+field+current:cur_pump`.

use anyhow::{bail, Result};
use magcomp_core::model::catalog::{info, info_of, AnyTerm, ChannelUse, TermKind, CATALOG};
use magcomp_core::model::{Model, Term};
use magcomp_core::MAX_AUX;

/// The input corrections a model can ask for: applied to the inputs before the filter, with
/// no filter state (the catalogue's zero-length entries). A spec writes them like terms
/// (`tl16+field+lag+fluxcal`), but they are a distinct kind from the deviation terms the
/// filter estimates, and the code recognises them by this type, not by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum InputCorrection {
    /// `lag`: the scalar's delay τ, estimated and re-aligned by fractional-delay
    /// interpolation.
    Lag,
    /// `fluxcal`: the fluxgate's 9-parameter scalar calibration (bias, scale,
    /// non-orthogonality).
    FluxCal,
    /// `fluxtemp:CH`: the fluxgate's bias/scale drift with a temperature channel.
    FluxTemp,
}

impl InputCorrection {
    pub const ALL: [InputCorrection; 3] = [Self::Lag, Self::FluxCal, Self::FluxTemp];

    /// Its catalogue entry (for the name a spec writes and the catalogue's description).
    pub const fn kind(self) -> TermKind {
        match self {
            Self::Lag => TermKind::Lag,
            Self::FluxCal => TermKind::FluxCal,
            Self::FluxTemp => TermKind::FluxTemp,
        }
    }

    /// The input correction a catalogue kind is, if it is one.
    pub fn of(kind: TermKind) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.kind() == kind)
    }

    /// The name a spec writes (`lag`, `fluxcal`, `fluxtemp`).
    pub const fn name(self) -> &'static str {
        self.kind().name()
    }
}

/// The paper's 16 deviation terms, written `tl16` in a spec.
pub const TL16: [TermKind; 3] = [TermKind::Permanent, TermKind::Induced, TermKind::Eddy];

/// One term of a spec: catalogue name and, for channel terms, the trace column. The name is
/// the spec's text (checked against the catalogue by [`ModelSpec::parse`]); code asks for
/// the typed [`kind`](Self::kind) or [`input_correction`](Self::input_correction).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TermSpec {
    pub name: String,
    pub channel: Option<String>,
}

impl TermSpec {
    /// A term of `kind` reading `channel`.
    pub fn of(kind: TermKind, channel: Option<String>) -> Self {
        Self {
            name: kind.name().to_string(),
            channel,
        }
    }

    /// The catalogue term this is (`None` only for a name outside the catalogue, which
    /// [`ModelSpec::parse`] refuses).
    pub fn kind(&self) -> Option<TermKind> {
        TermKind::from_name(&self.name)
    }

    /// The input correction this is, if it is one rather than a deviation term.
    pub fn input_correction(&self) -> Option<InputCorrection> {
        self.kind().and_then(InputCorrection::of)
    }

    /// The text a user writes for this term (`current:cur_pump`).
    pub fn text(&self) -> String {
        match &self.channel {
            Some(c) => format!("{}:{}", self.name, c),
            None => self.name.clone(),
        }
    }
}

/// A parsed model: whether the anomaly field is estimated, and the constant terms.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ModelSpec {
    pub field: bool,
    pub terms: Vec<TermSpec>,
}

/// The post-flight default: the paper's 16 deviation terms and anomaly field, with the
/// fluxgate calibrated against the scalar first. A fluxgate on an aircraft sits in the
/// aircraft's own field (tens to hundreds of nT), which turns its direction cosines by
/// milliradians and biases the induced coefficients: on the broad simulator's clean 3000 m
/// calibrations the paper's model alone was 1.12× TL18-OLS on one seed, with `fluxcal`
/// 0.41×. A flight whose attitudes do not determine the calibration leaves the fluxgate as
/// measured, with a warning (`fluxcal::MAX_DIRECTION_SIGMA_SHARE`).
pub const DEFAULT_MODEL: &str = "tl16+field+fluxcal";

/// The board's model (`boards/`): the paper's 16 terms and the field. The board applies a
/// fluxgate calibration loaded with `SETFLUX` but does not fit one.
pub const BOARD_MODEL: &str = "tl16+field";

/// The board's coefficient vector (`GETCOEF`/`SETCOEF` indices, its store): beside its
/// model the board runs that model with the fluxgate as a witness (docs/firmware.md,
/// "Fluxgate witness"), so the vector is the witnessed model's and a set of
/// [`BOARD_MODEL`] has `fluxmod` = 0.
pub const BOARD_COEFFICIENTS: &str = "tl16+field+fluxmod";

impl ModelSpec {
    /// Whether the model asks for the fluxgate's scalar calibration (`fluxcal`).
    pub fn calibrates_fluxgate(&self) -> bool {
        self.corrects(InputCorrection::FluxCal)
    }

    /// Whether the model has a term of `kind`.
    pub fn has(&self, kind: TermKind) -> bool {
        self.terms.iter().any(|t| t.kind() == Some(kind))
    }

    /// Whether the model asks for input correction `c`.
    pub fn corrects(&self, c: InputCorrection) -> bool {
        self.has(c.kind())
    }

    /// The spec entry of input correction `c` (its channel, for `fluxtemp`).
    pub fn correction(&self, c: InputCorrection) -> Option<&TermSpec> {
        self.terms.iter().find(|t| t.input_correction() == Some(c))
    }

    /// The deviation terms: every term but the input corrections.
    pub fn deviation_terms(&self) -> impl Iterator<Item = &TermSpec> {
        self.terms.iter().filter(|t| t.input_correction().is_none())
    }

    /// The same model without its input corrections: what the filter itself runs (the
    /// board's compiled model for a coefficient file).
    pub fn without_input_corrections(&self) -> ModelSpec {
        ModelSpec {
            field: self.field,
            terms: self.deviation_terms().cloned().collect(),
        }
    }

    pub fn parse(spec: &str) -> Result<Self> {
        let mut field = false;
        let mut terms: Vec<TermSpec> = Vec::new();
        let push = |t: TermSpec, terms: &mut Vec<TermSpec>| {
            if !terms.contains(&t) {
                terms.push(t);
            }
        };
        for raw in spec.split('+') {
            let part = raw.trim();
            if part.is_empty() {
                bail!("model spec '{spec}': empty term (two '+' in a row?)");
            }
            let (name, channel) = match part.split_once(':') {
                Some((n, c)) => (n.trim(), Some(c.trim().to_string())),
                None => (part, None),
            };
            match name {
                "field" => field = true,
                "tl16" => {
                    for k in TL16 {
                        push(TermSpec::of(k, None), &mut terms);
                    }
                }
                _ => {
                    let Some(ti) = info(name) else {
                        let known: Vec<&str> = CATALOG.iter().map(|t| t.name).collect();
                        bail!(
                            "model spec '{spec}': unknown term '{name}'. Known: tl16, field, {}",
                            known.join(", ")
                        );
                    };
                    let channel = match (ti.channel, channel) {
                        (ChannelUse::None, Some(c)) => {
                            bail!("model spec '{spec}': term '{name}' takes no channel (got ':{c}')")
                        }
                        (ChannelUse::None, None) => None,
                        (ChannelUse::Required, None) => bail!(
                            "model spec '{spec}': term '{name}' needs a channel, e.g. '{name}:cur_strobe'"
                        ),
                        (ChannelUse::Default(d), None) => Some(d.to_string()),
                        (_, Some(c)) if c.is_empty() => {
                            bail!("model spec '{spec}': term '{name}' has an empty channel name")
                        }
                        (_, Some(c)) => Some(c),
                    };
                    push(TermSpec::of(ti.kind, channel), &mut terms);
                }
            }
        }
        if terms.is_empty() && !field {
            bail!("model spec '{spec}' has no terms");
        }
        let s = Self { field, terms };
        if s.channels().len() > MAX_AUX {
            bail!("model spec '{spec}' uses more than {MAX_AUX} auxiliary channels");
        }
        Ok(s)
    }

    /// Canonical text (`permanent+induced+eddy` is written `tl16`).
    pub fn text(&self) -> String {
        let mut parts: Vec<String> = Vec::new();
        // (TL16's terms take no channel: one of them in the list is that term.)
        let has_tl16 = TL16.iter().all(|&k| self.has(k));
        if has_tl16 {
            parts.push("tl16".into());
        }
        if self.field {
            parts.push("field".into());
        }
        for t in &self.terms {
            if !(has_tl16 && t.kind().is_some_and(|k| TL16.contains(&k))) {
                parts.push(t.text());
            }
        }
        parts.join("+")
    }

    /// Auxiliary channels the model reads, in aux-index order.
    pub fn channels(&self) -> Vec<String> {
        let mut v: Vec<String> = Vec::new();
        for t in &self.terms {
            if let Some(c) = &t.channel {
                if !v.contains(c) {
                    v.push(c.clone());
                }
            }
        }
        v
    }

    /// Channels whose absolute level is meaningless (their first value is subtracted).
    pub fn relative_channels(&self) -> Vec<String> {
        self.terms
            .iter()
            .filter(|t| t.kind().is_some_and(|k| info_of(k).relative_channel))
            .filter_map(|t| t.channel.clone())
            .collect()
    }

    /// The same spec with one more term.
    pub fn with(&self, term: &str) -> Result<Self> {
        Self::parse(&format!("{}+{}", self.text(), term))
    }

    /// Builds the core terms (aux indices follow [`channels`](Self::channels)).
    pub fn build_terms(&self) -> Vec<AnyTerm> {
        let chans = self.channels();
        self.terms
            .iter()
            .map(|t| {
                let idx = t
                    .channel
                    .as_ref()
                    .and_then(|c| chans.iter().position(|x| x == c))
                    .unwrap_or(0);
                let kind = t
                    .kind()
                    .expect("spec names were checked against the catalogue");
                AnyTerm::of(kind, idx)
            })
            .collect()
    }

    /// Coefficient names `term.label` in state order.
    pub fn coefficient_names(&self) -> Vec<(String, String)> {
        let mut v = Vec::new();
        for (spec, t) in self.terms.iter().zip(self.build_terms()) {
            for i in 0..t.len() {
                v.push((
                    format!("{}.{}", spec.text(), t.label(i)),
                    t.unit(i).to_string(),
                ));
            }
        }
        v
    }
}

/// Runs `f` with a core [`Model`] borrowing the built terms.
pub fn with_model<R>(spec: &ModelSpec, f: impl FnOnce(Model<'_>) -> R) -> R {
    let terms = spec.build_terms();
    let refs: Vec<&dyn Term> = terms.iter().map(|t| t as &dyn Term).collect();
    f(Model {
        field: spec.field,
        terms: &refs,
    })
}

/// [`with_model`] for several models at once (one filter per sensor, all alive together).
pub fn with_models<R>(specs: &[&ModelSpec], f: impl FnOnce(Vec<Model<'_>>) -> R) -> R {
    let terms: Vec<Vec<AnyTerm>> = specs.iter().map(|s| s.build_terms()).collect();
    let refs: Vec<Vec<&dyn Term>> = terms
        .iter()
        .map(|t| t.iter().map(|t| t as &dyn Term).collect())
        .collect();
    f(specs
        .iter()
        .zip(&refs)
        .map(|(s, r)| Model {
            field: s.field,
            terms: r,
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_canonicalises() {
        let s = ModelSpec::parse("tl16+field").unwrap();
        assert!(s.field);
        assert_eq!(s.terms.len(), 3);
        assert_eq!(s.text(), "tl16+field");
        let s = ModelSpec::parse("permanent+induced+eddy+field+current:cur_pump+diurnal").unwrap();
        assert_eq!(s.text(), "tl16+field+current:cur_pump+diurnal:base");
        assert_eq!(
            s.channels(),
            vec!["cur_pump".to_string(), "base".to_string()]
        );
        assert_eq!(s.relative_channels(), vec!["base".to_string()]);
        let names = s.coefficient_names();
        assert_eq!(names.len(), 3 + 5 + 8 + 3 + 1);
        assert_eq!(names[0].0, "permanent.e1");
    }

    #[test]
    fn input_corrections_are_told_from_deviation_terms_by_type() {
        let s = ModelSpec::parse("tl16+field+lag+fluxcal+fluxtemp:temp1+rate").unwrap();
        for c in InputCorrection::ALL {
            assert!(s.corrects(c), "{c:?}");
            assert_eq!(InputCorrection::of(c.kind()), Some(c));
        }
        assert!(s.calibrates_fluxgate());
        assert!(s.has(TermKind::Rate));
        assert_eq!(
            s.correction(InputCorrection::FluxTemp)
                .and_then(|t| t.channel.as_deref()),
            Some("temp1")
        );
        assert_eq!(s.without_input_corrections().text(), "tl16+field+rate");
        assert_eq!(s.text(), "tl16+field+lag+fluxcal+fluxtemp:temp1+rate");
        let b = ModelSpec::parse(BOARD_MODEL).unwrap();
        assert!(InputCorrection::ALL.iter().all(|&c| !b.corrects(c)));
        assert_eq!(InputCorrection::of(TermKind::Rate), None);
    }

    #[test]
    fn rejects_bad_specs_with_clear_errors() {
        for (bad, needle) in [
            ("tl16++field", "empty term"),
            ("tl16+wobble", "unknown term 'wobble'"),
            ("tl16+current", "needs a channel"),
            ("tl16+eddy:x", "takes no channel"),
            ("", "empty term"),
        ] {
            let e = ModelSpec::parse(bad).unwrap_err().to_string();
            assert!(e.contains(needle), "{bad}: {e}");
        }
    }
}
