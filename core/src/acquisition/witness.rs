//! The fluxgate witness beside the paper model (`compensator::witness`): while the scalar
//! port sends single fields, channel 1's compensator, idle then, runs the witnessed model
//! on the same samples, and each record is the shown filter's. Counter lines need that
//! compensator for their second channel, so the witness stops when they arrive or when a
//! set is loaded for sensor 1 (an installation of several magnetometers).

use super::Acquisition;
use crate::compensator::witness::{Shown, WitnessChoice};
use crate::compensator::{Compensator, CompensatorError, Output};
use crate::model::Model;

impl<'a, const N: usize, const W: usize> Acquisition<'a, N, W> {
    /// Runs `model` (the paper model with `fluxmod`) beside the main filter from the next
    /// sample on, in calibrate mode. Refused while counter lines arrive.
    pub fn attach_witness(&mut self, model: Model<'a>) -> Result<(), CompensatorError> {
        if self.channels > 1 {
            return Err(CompensatorError::BadConfig);
        }
        self.extra[0].reset_in_place(model, *self.comp.config())?;
        self.witness = Some((model, self.fresh_choice()));
        Ok(())
    }

    fn fresh_choice(&self) -> WitnessChoice {
        WitnessChoice::for_rate(self.cfg.scalar_hz)
    }

    /// The witnessed filter and the choice, when one is attached ([`Flags::WITNESS`](crate::flags::Flags::WITNESS) marks
    /// its records).
    pub fn witness(&self) -> Option<(&Compensator<'a, N, W>, WitnessChoice)> {
        self.witness.map(|(_, choice)| (&self.extra[0], choice))
    }

    /// The filter whose records are shown (what `GETCOEF` and `SAVE` read).
    pub fn shown_compensator(&self) -> &Compensator<'a, N, W> {
        match self.witness {
            Some((_, choice)) if choice.shown() == Shown::Witness => &self.extra[0],
            _ => &self.comp,
        }
    }

    /// The record of this sample: the paper filter's, or the witnessed one's at the shown
    /// level (flagged [`Flags::WITNESS`](crate::flags::Flags::WITNESS)) when the choice says so.
    pub(super) fn shown_output(&mut self, paper: Output, witnessed: Option<Output>) -> Output {
        match (self.witness.as_mut(), witnessed) {
            (Some((_, choice)), Some(w)) => choice.show(paper, w),
            _ => paper,
        }
    }

    /// A set of the witnessed model's length loads into its filter, whose records are
    /// shown from then on; `None` when the set is not the witness's.
    pub(super) fn set_witness_coefficients(
        &mut self,
        c: &[f32],
    ) -> Option<Result<(), CompensatorError>> {
        let (model, choice) = self.witness.as_mut()?;
        if c.len() == model.coefficient_count() && c.len() != self.comp.model().coefficient_count()
        {
            let r = self.extra[0].set_coefficients(c);
            if r.is_ok() {
                choice.fix(Shown::Witness);
                self.comp.set_survey_mode(true);
            }
            return Some(r);
        }
        let r = self.comp.set_coefficients(c);
        if r.is_ok() {
            choice.fix(Shown::Paper);
            self.extra[0].set_survey_mode(true);
        }
        Some(r)
    }

    /// Survey mode freezes both filters and the choice as it stands; calibrate mode lets
    /// the flight choose again.
    pub(super) fn witness_survey_mode(&mut self, on: bool) {
        if let Some((_, choice)) = self.witness.as_mut() {
            if on {
                choice.freeze();
            } else {
                choice.release();
            }
        }
    }

    /// A filter restart restarts the witness too (same model, choice back to the paper's).
    pub(super) fn restart_witness(&mut self) -> Result<(), CompensatorError> {
        let fresh = self.fresh_choice();
        if let Some((model, choice)) = self.witness.as_mut() {
            self.extra[0].reset_in_place(*model, *self.comp.config())?;
            *choice = fresh;
        }
        Ok(())
    }

    /// Counter lines, or a set loaded for sensor 1, take channel 1's compensator back for
    /// their second sensor. Where the witnessed filter's records were shown, the paper
    /// filter starts afresh in calibrate mode: it was frozen beside the witness (or never
    /// shown), so its coefficients are not ones to show as good.
    pub(super) fn detach_witness(&mut self) {
        let Some((_, choice)) = self.witness.take() else {
            return;
        };
        let (model, cfg) = (*self.comp.model(), *self.comp.config());
        // Built with this model and configuration before, so neither can fail.
        let _ = self.extra[0].reset_in_place(model, cfg);
        if choice.shown() == Shown::Witness {
            let _ = self.comp.reset_in_place(model, cfg);
        }
    }
}
