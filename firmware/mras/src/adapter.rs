//! The MRAS adaptation (paper Fig. 6) as its own object: it consumes the
//! [`AdaptSample`]s the [`crate::Front`] leaves, and produces the decoupling vector's
//! [`InjectionUpdate`]s and the convergence measures. On the target it runs in a task
//! below the control interrupt; [`crate::Tracker`] runs it inline.

use crate::coefficients::{CoefficientsError, Convergence};
use crate::config::{Bank, Config, ConfigError, PathKind};
use crate::decoupler::{AdaptSample, Change, InjectionUpdate, PathBank};
use crate::observer::ObserverGains;
use crate::survey::{
    min_rad_of, next_round, ErrorSpectrum, ErrorSurvey, SurveyOutcome, FIRST_STAGE_MAX_REVS,
    SURVEY_PERIODS,
};
use crate::{Coefficients, MAX_PATHS, UPDATE_LATENCY_PERIODS};

#[derive(Clone, Debug)]
pub struct Adapter {
    bank: PathBank,
    /// The configuration, its paths the bank in use.
    cfg: Config,
    gains: ObserverGains,
    /// The configured paths: the fixed bank, or the first stage of one from the data.
    first: Bank,
    stage: Stage,
    survey: Option<SurveyOutcome>,
}

/// Where a bank from the data is ([`Config::paths_from_data`]): rounds of adapting the
/// bank so far until it converges, then surveying what it leaves and growing it, until a
/// round adds nothing or the bank is full.
#[derive(Clone, Debug)]
enum Stage {
    /// The bank is complete: the configured one, or the surveys'.
    Complete,
    /// The bank so far (the configured paths first) adapts until it converges.
    Adapt,
    /// Adaptation paused while the spectrum of what is left is measured.
    Survey(ErrorSurvey),
}

impl Adapter {
    pub fn new(cfg: &Config) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let gains = ObserverGains::from_eigenvalues(
            cfg.observer.eigenvalues_hz,
            cfg.observer.inertia_kg_m2,
        );
        Ok(Self {
            bank: PathBank::new(cfg, &gains),
            cfg: *cfg,
            gains,
            first: Bank::new(cfg.paths()),
            stage: if cfg.paths_from_data {
                Stage::Adapt
            } else {
                Stage::Complete
            },
            survey: None,
        })
    }

    /// One accepted sample, in the order the front produced them. Returns whether the
    /// adaptation ran on it (gates open, not frozen) and the update it made, if any: the
    /// term of the path whose block it completed, or the survey's new bank.
    #[inline]
    pub fn step(&mut self, s: &AdaptSample) -> (bool, Option<InjectionUpdate>) {
        if !matches!(self.stage, Stage::Complete) {
            return self.step_choosing(s);
        }
        let revs = self.bank.revs_adapted;
        let out = self.bank.step(s);
        // Once a revolution until armed: a converged bank arms the transient gate.
        if self.bank.revs_adapted != revs
            && !self.bank.transient_gate_armed()
            && self.judge().converged
        {
            self.bank.arm_transient_gate();
        }
        out
    }

    /// [`Self::step`] while a bank from the data is being chosen: out of the common
    /// path (its own copy of the bank step keeps the complete bank's step as it was).
    #[inline(never)]
    fn step_choosing(&mut self, s: &AdaptSample) -> (bool, Option<InjectionUpdate>) {
        let revs = self.bank.revs_adapted;
        // While surveying, residuals are still measured but nothing adapts.
        let surveying = matches!(self.stage, Stage::Survey(_));
        let flags = s.flags | if surveying { AdaptSample::FROZEN } else { 0 };
        let out = self.bank.step(&AdaptSample { flags, ..*s });
        if surveying {
            // At a sample without a term update: one update per sample.
            if let Some(u) = self.survey_sample(s, out.1.is_none()) {
                return (false, Some(u));
            }
        }
        // Once a revolution: a converged bank ends the round's adaptation.
        if self.bank.revs_adapted != revs
            && matches!(self.stage, Stage::Adapt)
            && (self.judge().converged || self.bank.revs_adapted >= FIRST_STAGE_MAX_REVS)
        {
            self.stage = Stage::Survey(ErrorSurvey::default());
        }
        out
    }

    /// One sample of a survey (out of the common path: a few seconds at commissioning);
    /// the new bank when the survey completes on a sample free for an update.
    #[inline(never)]
    fn survey_sample(&mut self, s: &AdaptSample, free: bool) -> Option<InjectionUpdate> {
        let Stage::Survey(survey) = &mut self.stage else {
            return None;
        };
        if s.has(AdaptSample::LOCKED) && !s.has(AdaptSample::RESTART) {
            let n = self.cfg.sensor_periods as f32;
            survey.add(s.u, s.eps_e_rad, n * s.omega_rad_s);
        } else {
            // Whole periods of one lock only.
            *survey = ErrorSurvey::default();
        }
        if !(free && survey.periods() >= SURVEY_PERIODS) {
            return None;
        }
        let spectrum = survey.spectrum(&self.gains)?;
        self.end_round(&spectrum, s.index)
    }

    /// A survey is complete: the bank grows by what it found, in force like a path's
    /// term, and adapts again; or nothing was found (or the bank is full) and the bank is
    /// complete.
    #[inline(never)]
    fn end_round(&mut self, spectrum: &ErrorSpectrum, index: u32) -> Option<InjectionUpdate> {
        let outcome = self.survey.get_or_insert(SurveyOutcome {
            spectrum: *spectrum,
            min_rad: min_rad_of(spectrum),
            bank: self.first,
            unobserved: heapless::Vec::new(),
            rounds: 0,
        });
        let (bank, complete, unobserved) = next_round(spectrum, self.cfg.paths(), outcome.min_rad);
        outcome.rounds = outcome.rounds.saturating_add(1);
        outcome.bank = bank;
        outcome.unobserved = unobserved;
        let grown = bank.as_slice() != self.cfg.paths();
        if grown {
            self.rebank(bank);
        }
        self.stage = if complete {
            Stage::Complete
        } else {
            Stage::Adapt
        };
        grown.then(|| InjectionUpdate {
            apply_at: index.wrapping_add(UPDATE_LATENCY_PERIODS),
            change: Change::Bank(bank.into()),
        })
    }

    /// Run `bank` from now on (validated by the caller).
    #[inline(never)]
    fn rebank(&mut self, bank: Bank) {
        // `bank` holds at most MAX_PATHS kinds, so this cannot fail.
        let _ = self.cfg.set_paths(bank.as_slice());
        self.bank.rebank(&self.cfg, &self.gains);
    }

    /// What the surveys chose so far (`None` with a fixed bank, before the first survey,
    /// or when the bank came from flash).
    pub fn survey(&self) -> Option<&SurveyOutcome> {
        self.survey.as_ref()
    }

    /// Whether a bank from the data is still being chosen.
    pub fn surveying(&self) -> bool {
        !matches!(self.stage, Stage::Complete)
    }

    /// Snapshot of the persistent coefficients (proportional parts excluded).
    pub fn coefficients(&self) -> Coefficients {
        let mut c = Coefficients::zeros(self.cfg.paths());
        // `take`, not `[..len]`: no panic path.
        for (v, s) in c
            .values
            .iter_mut()
            .zip(self.bank.state.iter().take(self.bank.len))
        {
            *v = s.coef;
        }
        c
    }

    /// Check coefficients (e.g. from flash) and start from them. Refused unless the paths
    /// match the bank in use (or, with [`Config::paths_from_data`], form a valid bank that
    /// starts with the configured paths: then it becomes the bank) and every value is
    /// finite and within the coefficient limit. The front's decoupling vector is the
    /// caller's to load ([`crate::Front::load_injection`]).
    pub fn set_coefficients(&mut self, c: &Coefficients) -> Result<(), CoefficientsError> {
        let kinds = c.kinds();
        let same = kinds == self.cfg.paths();
        if !same && !self.accepts_bank(kinds) {
            return Err(CoefficientsError::PathMismatch);
        }
        let limit = self.cfg.health.coefficient_limit * self.cfg.health.amplitude_max;
        if c.iter().any(|(_, v)| !v.is_finite() || v.abs() > limit) {
            return Err(CoefficientsError::OutOfRange);
        }
        if !same {
            self.rebank(Bank::new(kinds));
        }
        self.bank.load(c.iter().map(|(_, v)| v));
        self.stage = Stage::Complete;
        Ok(())
    }

    /// A bank from the data may be any valid bank that starts with the first stage.
    fn accepts_bank(&self, kinds: &[PathKind]) -> bool {
        let mut cfg = self.cfg;
        self.cfg.paths_from_data
            && kinds.starts_with(self.first.as_slice())
            && cfg.set_paths(kinds).is_ok()
            && {
                cfg.paths_from_data = false;
                cfg.validate().is_ok()
            }
    }

    /// Convergence measures and the `converged` judgement: never converged while a bank
    /// from the data is still being chosen.
    pub fn convergence(&self) -> Convergence {
        let mut c = self.judge();
        c.converged &= !self.surveying();
        c
    }

    /// The measures and judgement of the bank in use.
    fn judge(&self) -> Convergence {
        let cc = &self.cfg.convergence;
        let mut out = Convergence {
            residual_rad: [0.0; MAX_PATHS],
            change_per_rev: [0.0; MAX_PATHS],
            len: self.bank.len as u8,
            revs_adapted: self.bank.revs_adapted,
            unseen_paths: 0,
            converged: false,
        };
        let mut all_small = true;
        let per_path = out
            .residual_rad
            .iter_mut()
            .zip(out.change_per_rev.iter_mut());
        let revs = self.bank.revs_adapted;
        let states = self.bank.state.iter().take(self.bank.len);
        for (i, (s, (residual, change))) in states.zip(per_path).enumerate() {
            *residual = s.residual.abs();
            *change = s.change_last_rev;
            all_small &= *residual < cc.residual_rad && *change < cc.change_per_rev;
            if s.visible_rev.is_none_or(|r| r.saturating_add(1) < revs) {
                out.unseen_paths |= 1 << i;
            }
        }
        out.converged =
            all_small && out.unseen_paths == 0 && self.bank.revs_adapted >= cc.min_revs as u32;
        out
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }
}
