//! The MRAS adaptation (paper Fig. 6) as its own object: it consumes the
//! [`AdaptSample`]s the [`crate::Front`] leaves, and produces the decoupling vector's
//! [`InjectionUpdate`]s and the convergence measures. On the target it runs in a task
//! below the control interrupt; [`crate::Tracker`] runs it inline.

use crate::coefficients::{CoefficientsError, Convergence};
use crate::complex::Cplx;
use crate::config::{Bank, Config, ConfigError, PathKind};
use crate::decoupler::{AdaptSample, BankPlan, Change, InjectionUpdate, PackedBank, PathBank};
use crate::observer::ObserverGains;
use crate::survey::{
    min_rad_of, ErrorSpectrum, ErrorSurvey, NextRound, SurveyOutcome, FIRST_STAGE_MAX_REVS,
    SURVEY_PERIODS,
};
use crate::{Coefficients, UPDATE_LATENCY_PERIODS};

#[derive(Clone, Debug)]
pub struct Adapter {
    /// The bank in use (`active`) and the one a survey round builds aside: putting the
    /// new one in force flips `active`, where moving it over copied 1.6 kB in the task.
    banks: [PathBank; 2],
    active: usize,
    /// The configuration, its paths the bank in use.
    cfg: Config,
    gains: ObserverGains,
    /// The configured paths: the fixed bank, or the first stage of one from the data.
    first: Bank,
    stage: Stage,
    survey: Option<SurveyOutcome>,
    /// The last bank change worked out against the bank before it, for the front.
    plan: Option<BankPlan>,
    /// The bank in use, packed.
    packed: PackedBank,
    /// The configuration with a survey round's bank, worked out once for its steps.
    next_cfg: Config,
}

/// The bank of `banks` a survey round builds aside while `active` is in use.
fn spare(banks: &mut [PathBank; 2], active: usize) -> &mut PathBank {
    let [a, b] = banks;
    if active & 1 == 0 {
        b
    } else {
        a
    }
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
    /// A survey's end, a step a sample (all at once it took several control periods of
    /// the task's time), adaptation still paused.
    EndRound(EndRound),
}

/// The steps of a survey's end.
// One at a time, worked in place: no allocator to box the largest.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum EndRound {
    /// The spectrum is measured: the next sample starts choosing the paths.
    Measured(ErrorSpectrum),
    /// The paths being chosen, a phase a sample.
    Choosing(NextRound),
    /// The paths are chosen; the next samples work the bank's steps.
    Chosen(RoundChoice, Next),
}

/// What a survey round chose.
#[derive(Clone, Copy, Debug)]
struct RoundChoice {
    bank: Bank,
    /// The surveys are over.
    complete: bool,
    /// The bank differs from the one in use.
    grown: bool,
    /// `bank` packed, once its plan is made.
    packed: PackedBank,
}

/// The next step of a chosen bank.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Next {
    /// Its plan against the bank in use, in three steps: the bank packed, its layout,
    /// and the terms it keeps.
    Pack,
    Layout,
    Keep,
    /// Its adaptation, built aside in three steps: the paths' state, the rest, the
    /// law's constants and the transient gate.
    BuildState,
    BuildRest,
    BuildLaw,
    /// In force, on the next sample free for an update.
    PutInForce,
}

impl Adapter {
    pub fn new(cfg: &Config) -> Result<Self, ConfigError> {
        cfg.validate()?;
        let gains = ObserverGains::from_eigenvalues(
            cfg.observer.eigenvalues_hz,
            cfg.observer.inertia_kg_m2,
        );
        let bank = PathBank::new(cfg, &gains);
        Ok(Self {
            banks: [bank; 2],
            active: 0,
            cfg: *cfg,
            gains,
            first: Bank::new(cfg.paths()),
            stage: if cfg.paths_from_data {
                Stage::Adapt
            } else {
                Stage::Complete
            },
            survey: None,
            plan: None,
            packed: Bank::new(cfg.paths()).into(),
            next_cfg: *cfg,
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
        let revs = self.bank().revs_adapted;
        let out = self.bank_mut().step(s);
        // Once a revolution until armed: a converged bank arms the transient gate.
        if self.bank().revs_adapted != revs
            && !self.bank().transient_gate_armed()
            && self.judge().converged
        {
            self.bank_mut().arm_transient_gate();
        }
        out
    }

    /// [`Self::step`] while a bank from the data is being chosen: out of the common
    /// path (its own copy of the bank step keeps the complete bank's step as it was).
    #[inline(never)]
    fn step_choosing(&mut self, s: &AdaptSample) -> (bool, Option<InjectionUpdate>) {
        let revs = self.bank().revs_adapted;
        // While surveying, residuals are still measured but nothing adapts.
        let surveying = matches!(self.stage, Stage::Survey(_) | Stage::EndRound(_));
        let flags = s.flags | if surveying { AdaptSample::FROZEN } else { 0 };
        let out = self.bank_mut().step(&AdaptSample { flags, ..*s });
        // At a sample without a term update: one update per sample.
        let free = out.1.is_none();
        match &self.stage {
            Stage::Survey(_) => self.survey_sample(s),
            Stage::EndRound(_) => {
                if let Some(u) = self.end_round_step(s.index, free) {
                    return (false, Some(u));
                }
            }
            _ => {}
        }
        // Once a revolution: a converged bank ends the round's adaptation.
        if self.bank().revs_adapted != revs
            && matches!(self.stage, Stage::Adapt)
            && (self.judge().converged || self.bank().revs_adapted >= FIRST_STAGE_MAX_REVS)
        {
            self.stage = Stage::Survey(ErrorSurvey::default());
        }
        out
    }

    /// One sample of a survey (out of the common path: a few seconds at commissioning);
    /// at its end the spectrum, the first step of [`EndRound`].
    #[inline(never)]
    fn survey_sample(&mut self, s: &AdaptSample) {
        let Stage::Survey(survey) = &mut self.stage else {
            return;
        };
        if s.has(AdaptSample::LOCKED) && !s.has(AdaptSample::RESTART) {
            let n = self.cfg.sensor_periods as f32;
            survey.add(s.u, s.eps_e_rad, n * s.omega_rad_s);
        } else {
            // Whole periods of one lock only.
            *survey = ErrorSurvey::default();
        }
        if survey.periods() < SURVEY_PERIODS {
            return;
        }
        if let Some(spectrum) = survey.spectrum(&self.gains) {
            self.stage = Stage::EndRound(EndRound::Measured(spectrum));
        }
    }

    /// The next step of a survey's end: the bank grows by what the spectrum shows (its
    /// plan made), then, on a sample free for an update, it is in force like a path's
    /// term and adapts again; or nothing was found (or the bank is full) and the bank
    /// is complete.
    #[inline(never)]
    fn end_round_step(&mut self, index: u32, free: bool) -> Option<InjectionUpdate> {
        let Stage::EndRound(step) = &self.stage else {
            return None;
        };
        let (choice, next) = match step {
            EndRound::Measured(spectrum) => {
                let spectrum = *spectrum;
                let outcome = self.survey.get_or_insert(SurveyOutcome {
                    spectrum,
                    min_rad: min_rad_of(&spectrum),
                    bank: self.first,
                    unobserved: heapless::Vec::new(),
                    rounds: 0,
                });
                let round = NextRound::new(spectrum, Bank::new(self.cfg.paths()), outcome.min_rad);
                self.stage = Stage::EndRound(EndRound::Choosing(round));
                return None;
            }
            EndRound::Choosing(_) => {
                self.choose_step();
                return None;
            }
            &EndRound::Chosen(choice, next) => (choice, next),
        };
        let mut choice = choice;
        let RoundChoice {
            bank,
            complete,
            grown,
            packed,
        } = choice;
        let after = match next {
            Next::Pack => {
                if grown {
                    choice.packed = bank.into();
                    self.next_cfg = self.cfg;
                    // `bank` holds at most MAX_PATHS kinds, so this cannot fail.
                    let _ = self.next_cfg.set_paths(bank.as_slice());
                }
                Next::Layout
            }
            Next::Layout => {
                if grown {
                    self.plan
                        .get_or_insert(BankPlan::EMPTY)
                        .lay_out(bank.as_slice(), packed);
                }
                Next::Keep
            }
            Next::Keep => {
                if let (true, Some(plan)) = (grown, &mut self.plan) {
                    plan.keep_from(self.cfg.paths(), self.packed);
                }
                Next::BuildState
            }
            Next::BuildState => {
                if grown {
                    spare(&mut self.banks, self.active).renew_state();
                }
                Next::BuildRest
            }
            Next::BuildRest => {
                if grown {
                    spare(&mut self.banks, self.active).renew_rest(&self.next_cfg);
                }
                Next::BuildLaw
            }
            Next::BuildLaw => {
                if grown {
                    spare(&mut self.banks, self.active).renew_law(&self.next_cfg, &self.gains);
                }
                Next::PutInForce
            }
            Next::PutInForce => {
                if !free {
                    return None;
                }
                if grown {
                    self.put_built(bank, packed);
                }
                self.stage = if complete {
                    Stage::Complete
                } else {
                    Stage::Adapt
                };
                return grown.then_some(InjectionUpdate {
                    apply_at: index.wrapping_add(UPDATE_LATENCY_PERIODS),
                    change: Change::Bank(packed),
                });
            }
        };
        // In place: a new stage written whole copied the largest of its kinds.
        if let Stage::EndRound(EndRound::Chosen(c, n)) = &mut self.stage {
            c.packed = choice.packed;
            *n = after;
        }
        None
    }

    /// A phase of the paths' choice; the last records the round and moves on to the
    /// chosen bank's steps.
    #[inline(never)]
    fn choose_step(&mut self) {
        let Stage::EndRound(EndRound::Choosing(round)) = &mut self.stage else {
            return;
        };
        if !round.step() {
            return;
        }
        let (&bank, complete, unobserved) = round.chosen();
        if let Some(outcome) = &mut self.survey {
            outcome.rounds = outcome.rounds.saturating_add(1);
            outcome.bank = bank;
            outcome.unobserved = unobserved.clone();
        }
        let grown = bank.as_slice() != self.cfg.paths();
        let choice = RoundChoice {
            bank,
            complete,
            grown,
            packed: PackedBank::EMPTY,
        };
        self.stage = Stage::EndRound(EndRound::Chosen(choice, Next::Pack));
    }

    /// The bank in use.
    #[inline(always)]
    fn bank(&self) -> &PathBank {
        &self.banks[self.active & 1]
    }

    #[inline(always)]
    fn bank_mut(&mut self) -> &mut PathBank {
        &mut self.banks[self.active & 1]
    }

    /// Run `bank` from now on (validated by the caller).
    #[inline(never)]
    fn rebank(&mut self, bank: Bank) {
        self.plan = Some(BankPlan::new(self.cfg.paths(), bank.as_slice()));
        self.rebank_planned(bank);
    }

    /// [`Self::rebank`] with its plan made.
    #[inline(never)]
    fn rebank_planned(&mut self, bank: Bank) {
        self.packed = bank.into();
        self.plan_for(bank, self.packed);
        // `bank` holds at most MAX_PATHS kinds, so this cannot fail.
        let _ = self.cfg.set_paths(bank.as_slice());
        if let Some(plan) = &self.plan {
            self.banks[self.active & 1].rebank(&self.cfg, &self.gains, plan);
        }
    }

    /// A survey round's bank (`packed`, the same) in force: the one built in
    /// [`Self::next`] takes over what the bank in use carries.
    #[inline(never)]
    fn put_built(&mut self, bank: Bank, packed: PackedBank) {
        self.plan_for(bank, packed);
        self.packed = packed;
        let _ = self.cfg.set_paths(bank.as_slice());
        if let Some(plan) = &self.plan {
            let [a, b] = &mut self.banks;
            let (old, new) = if self.active & 1 == 0 { (a, b) } else { (b, a) };
            new.carry_from(old, plan);
        }
        self.active ^= 1;
    }

    /// [`Self::plan`] made for `bank` (`packed`, the same), unless it is.
    fn plan_for(&mut self, bank: Bank, packed: PackedBank) {
        if !self.plan.as_ref().is_some_and(|p| p.bank() == packed) {
            self.plan = Some(BankPlan::new(self.cfg.paths(), bank.as_slice()));
        }
    }

    /// The plan of the last bank change this adapter made (a survey's round, or
    /// coefficients of another bank), for the copy of the front's decoupling vector the
    /// task keeps ([`crate::Injection::apply`]).
    pub fn plan(&self) -> Option<&BankPlan> {
        self.plan.as_ref()
    }

    /// What the surveys chose so far (`None` with a fixed bank, before the first survey,
    /// or when the bank came from flash).
    pub fn survey(&self) -> Option<&SurveyOutcome> {
        self.survey.as_ref()
    }

    /// Whether a survey's end is under way: each of its samples works one of its steps
    /// (see [`EndRound`]).
    pub fn ending_round(&self) -> bool {
        matches!(self.stage, Stage::EndRound(_))
    }

    /// Whether a bank from the data is still being chosen.
    pub fn surveying(&self) -> bool {
        !matches!(self.stage, Stage::Complete)
    }

    /// Snapshot of the persistent coefficients (proportional parts excluded).
    pub fn coefficients(&self) -> Coefficients {
        let mut c = Coefficients::EMPTY;
        self.coefficients_into(&mut c);
        c
    }

    /// [`Self::coefficients`] written into `out` (no 200-byte value to build and copy).
    pub fn coefficients_into(&self, out: &mut Coefficients) {
        out.set_kinds(self.cfg.paths());
        // `take`, not `[..len]`: no panic path.
        let mut states = self.bank().state.iter().take(self.bank().len);
        for v in out.values.iter_mut() {
            *v = states.next().map_or(Cplx::ZERO, |s| s.coef);
        }
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
        self.bank_mut().load(c.iter().map(|(_, v)| v));
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
        let mut c = Convergence::EMPTY;
        self.convergence_into(&mut c);
        c
    }

    /// [`Self::convergence`] written into `out` (the adaptation task's report, once a
    /// supervisor period: no 140-byte value to build and copy).
    pub fn convergence_into(&self, out: &mut Convergence) {
        self.judge_into(out);
        out.converged &= !self.surveying();
    }

    /// The measures and judgement of the bank in use.
    fn judge(&self) -> Convergence {
        let mut c = Convergence::EMPTY;
        self.judge_into(&mut c);
        c
    }

    /// [`Self::judge`] into `out`; entries beyond the bank are left as they were.
    fn judge_into(&self, out: &mut Convergence) {
        let cc = &self.cfg.convergence;
        let bank = self.bank();
        let revs = bank.revs_adapted;
        out.len = bank.len as u8;
        out.revs_adapted = revs;
        let mut unseen = 0;
        let mut all_small = true;
        let per_path = out
            .residual_rad
            .iter_mut()
            .zip(out.change_per_rev.iter_mut());
        for (i, (s, (residual, change))) in
            bank.state.iter().take(bank.len).zip(per_path).enumerate()
        {
            *residual = s.residual.abs();
            *change = s.change_last_rev;
            all_small &= *residual < cc.residual_rad && *change < cc.change_per_rev;
            if s.visible_rev.is_none_or(|r| r.saturating_add(1) < revs) {
                unseen |= 1 << i;
            }
        }
        out.unseen_paths = unseen;
        out.converged = all_small && unseen == 0 && revs >= cc.min_revs as u32;
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }
}
