//! The MRAS adaptation's side of the drive: a task below the control period.
//!
//! The control period ([`crate::control::ControlPeriod::step`]) hands every accepted
//! sample over ([`crate::control::ControlPeriod::hand_over`]); [`AdaptationTask::run`]
//! turns them into the decoupling vector's updates, which go back through
//! [`crate::control::ControlPeriod::apply_due`], in force a fixed latency after their
//! sample ([`mras::UPDATE_LATENCY_PERIODS`]). The queues and the task's loop are
//! [`crate::handoff`]'s, the firmware's and hil-sim's alike, so both compute the same bits.
//!
//! The convergence measures and coefficients the supervisor needs are computed here,
//! once per snapshot ([`mras::AdaptSample::REPORT`]), not in the control interrupt.
//!
//! An update the queue cannot take is never lost silently: it is counted
//! ([`AdaptReport::updates_dropped`]) and owed. While anything is owed nothing else is
//! queued; once there is room the owed bank goes first, then each owed path's newest
//! term. A bank change that did not fit owes every path of the new bank at the adapter's
//! coefficient (the terms owed before index the old bank; a path's proportional part
//! follows with its next update), so the control period never applies a term to another
//! bank than the adapter's, and never runs on the old bank once there is room.

use crate::handoff::{Prepared, Receiver, Sender};
use crate::telemetry::{Install, InstallAck, Snapshot, Telemetry};
use core::borrow::BorrowMut;
use mras::{
    AdaptSample, Adapter, Bank, Change, Coefficients, ConfigError, Convergence, Cplx, Injection,
    InjectionUpdate, MAX_PATHS, UPDATE_LATENCY_PERIODS,
};

/// What the adaptation reports to the supervisor (merged into its [`Telemetry`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdaptReport {
    pub converged: bool,
    pub revs: u32,
    /// Largest per-path residual (`mras::Convergence::residual_rad`).
    pub residual_max_rad: f32,
    pub coefficients: Coefficients,
    /// The answer to the last [`Install`].
    pub install: Option<InstallAck>,
    /// Updates the queue back to the control period could not take when they were made,
    /// since start (see the module's doc): the control period lagged the adapter.
    pub updates_dropped: u32,
}

impl AdaptReport {
    /// Nothing measured yet.
    pub const EMPTY: Self = Self {
        converged: false,
        revs: 0,
        residual_max_rad: f32::INFINITY,
        coefficients: Coefficients::EMPTY,
        install: None,
        updates_dropped: 0,
    };
}

impl Default for AdaptReport {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// The adaptation task's state; `S` holds the decoupling vector it builds a new bank
/// in ([`crate::handoff`]).
#[derive(Clone, Debug)]
pub struct AdaptationTask<S: BorrowMut<Injection> = Injection> {
    adapter: Adapter,
    /// The control period's decoupling vector as of every update queued to it, each in
    /// force here as it was queued: a new bank's vector is built from it.
    mirror: Injection,
    /// The buffer the next bank is built in (`None`: handed over, not back yet).
    spare: Option<S>,
    /// A survey round's bank, queued by the next run (or step): the step that makes it
    /// moves the adapter over to it, building its vector would make that run too long.
    deferred: Option<InjectionUpdate>,
    report: AdaptReport,
    /// The adapter's convergence measures, written in place at each report.
    convergence: Convergence,
    /// The period of the last sample adapted on.
    last_index: u32,
    owed: Owed,
    updates_dropped: u32,
}

/// Updates owed to the control period (see the module's doc).
#[derive(Clone, Copy, Debug)]
struct Owed {
    /// A new bank, sent first.
    bank: Option<InjectionUpdate>,
    /// Bit i: path i's term `terms[i]` (due period, value) is owed.
    paths: u32,
    terms: [(u32, Cplx); MAX_PATHS],
    /// Where the next attempt starts: round robin, so that a path updated often cannot
    /// keep the others waiting.
    next: usize,
}

const _: () = assert!(MAX_PATHS <= 32, "one bit of Owed::paths per path");

impl Owed {
    const NONE: Self = Self {
        bank: None,
        paths: 0,
        terms: [(0, Cplx::ZERO); MAX_PATHS],
        next: 0,
    };
}

impl AdaptationTask {
    pub fn new(cfg: &mras::Config) -> Result<Self, ConfigError> {
        Self::with_spare(cfg, Injection::EMPTY)
    }
}

impl<S: BorrowMut<Injection>> AdaptationTask<S> {
    /// The task, `spare` the buffer it builds the first new bank's decoupling vector in.
    pub fn with_spare(cfg: &mras::Config, spare: S) -> Result<Self, ConfigError> {
        let adapter = Adapter::new(cfg)?;
        let mut a = Self {
            report: AdaptReport::EMPTY,
            convergence: Convergence::EMPTY,
            mirror: Injection::new(cfg.paths()),
            spare: Some(spare),
            deferred: None,
            adapter,
            last_index: 0,
            owed: Owed::NONE,
            updates_dropped: 0,
        };
        a.measure();
        Ok(a)
    }

    /// One handed-over sample; its update, if one is due, goes to `updates` (a new
    /// bank's decoupling vector to `banks` ahead of it).
    pub fn step(
        &mut self,
        s: &AdaptSample,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) {
        self.send_deferred(updates, banks);
        self.last_index = s.index;
        let (_, update) = self.adapter.step(s);
        match update {
            Some(u) if matches!(u.change, Change::Bank(_)) => self.deferred = Some(u),
            Some(u) => self.send(u, updates, banks),
            None => {}
        }
        if s.has(AdaptSample::REPORT) {
            self.measure();
        }
    }

    /// Coefficients loaded from flash: validated by the core; if accepted, the bank and
    /// every path's term go to the control period through `updates`, in force with the
    /// update of the last sample adapted on (after every update already queued, whose
    /// order is their due order; on time if the task is).
    pub fn install(
        &mut self,
        i: &Install,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) {
        let before = Bank::new(self.adapter.config().paths());
        let accepted = self.adapter.set_coefficients(&i.coefficients).is_ok();
        if accepted {
            let apply_at = self.last_index.wrapping_add(UPDATE_LATENCY_PERIODS);
            // A record's bank from the data differs from the first stage in use: the
            // bank first (the front follows the adapter's every change), then every term.
            let bank = Bank::new(self.adapter.config().paths());
            if bank != before {
                let change = Change::Bank(bank.into());
                self.send(InjectionUpdate { apply_at, change }, updates, banks);
            }
            for (path, (_, value)) in i.coefficients.iter().enumerate() {
                let change = Change::Term {
                    path: path as u8,
                    value,
                };
                self.send(InjectionUpdate { apply_at, change }, updates, banks);
            }
        }
        self.report.install = Some(InstallAck {
            generation: i.generation,
            accepted,
        });
        self.measure();
    }

    /// The bank a step deferred, queued (its vector built) ahead of anything after it.
    pub(crate) fn send_deferred(
        &mut self,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) {
        if let Some(u) = self.deferred.take() {
            self.send(u, updates, banks);
        }
    }

    /// A decoupling vector the control period handed back, as the spare.
    pub(crate) fn take_spare(&mut self, spares: &mut impl Receiver<S>) {
        if self.spare.is_none() {
            self.spare = spares.receive();
        }
    }

    /// Queue `u` behind whatever is owed, or owe it.
    fn send(
        &mut self,
        u: InjectionUpdate,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) {
        let queued = self.send_owed(updates, banks) && self.enqueue(u, updates, banks);
        if !queued {
            self.updates_dropped = self.updates_dropped.saturating_add(1);
            self.owe(u);
        }
    }

    /// Queue `u` (`false`: no room), and put it in force in the mirror. A new bank's
    /// decoupling vector goes to `banks` ahead of it when the spare is at hand.
    fn enqueue(
        &mut self,
        u: InjectionUpdate,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) -> bool {
        if !updates.ready() {
            return false;
        }
        self.mirror.apply(&u.change, self.adapter.plan());
        if matches!(u.change, Change::Bank(_)) {
            self.hand_over_bank(u.apply_at, banks);
        }
        // Cannot be refused: ready, and this task is the queue's only producer.
        updates.send(u).is_ok()
    }

    /// The mirror, a new bank in force in it, copied into the spare for the bank's
    /// update due at `apply_at`.
    #[inline(never)]
    fn hand_over_bank(&mut self, apply_at: u32, banks: &mut impl Sender<Prepared<S>>) {
        if let Some(mut injection) = self.spare.take() {
            *injection.borrow_mut() = self.mirror;
            if let Err(p) = banks.send(Prepared {
                apply_at,
                injection,
            }) {
                self.spare = Some(p.injection);
            }
        }
    }

    fn owe(&mut self, u: InjectionUpdate) {
        let owed = &mut self.owed;
        match u.change {
            Change::Term { path, value } => {
                if let Some(t) = owed.terms.get_mut(path as usize) {
                    *t = (u.apply_at, value);
                    owed.paths |= 1 << path;
                }
            }
            Change::Bank(_) => {
                owed.bank = Some(u);
                owed.paths = 0;
                let c = self.adapter.coefficients();
                for (i, (t, (_, v))) in owed.terms.iter_mut().zip(c.iter()).enumerate() {
                    *t = (u.apply_at, v);
                    owed.paths |= 1 << i;
                }
            }
        }
    }

    /// Send what is owed, the bank first; true when nothing is owed any more.
    pub(crate) fn send_owed(
        &mut self,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
    ) -> bool {
        if let Some(b) = self.owed.bank {
            if !self.enqueue(b, updates, banks) {
                return false;
            }
            self.owed.bank = None;
        }
        for k in 0..MAX_PATHS {
            if self.owed.paths == 0 {
                break;
            }
            let i = (self.owed.next + k) % MAX_PATHS;
            let Some(&(apply_at, value)) = self.owed.terms.get(i) else {
                break;
            };
            if self.owed.paths & (1 << i) == 0 {
                continue;
            }
            let change = Change::Term {
                path: i as u8,
                value,
            };
            if !self.enqueue(InjectionUpdate { apply_at, change }, updates, banks) {
                self.owed.next = i;
                return false;
            }
            self.owed.paths &= !(1 << i);
        }
        self.owed.paths == 0
    }

    /// The report as of the last snapshot sample (or install).
    pub fn report(&self) -> &AdaptReport {
        &self.report
    }

    pub fn adapter(&self) -> &Adapter {
        &self.adapter
    }

    /// [`AdaptReport::updates_dropped`] as of now (the report has it as of its last
    /// snapshot sample).
    pub fn updates_dropped(&self) -> u32 {
        self.updates_dropped
    }

    /// The report from the adapter, written where it lies (once a supervisor period, in
    /// the run of a sample: building it aside and copying it cost as much again).
    fn measure(&mut self) {
        self.adapter.convergence_into(&mut self.convergence);
        let c = &self.convergence;
        let r = &mut self.report;
        r.converged = c.converged;
        r.revs = c.revs_adapted;
        // A comparison, not `f32::max` (a library call here); a NaN is skipped by both.
        r.residual_max_rad = 0.0;
        for &x in c.residual_rad.iter().take(c.len as usize) {
            if x > r.residual_max_rad {
                r.residual_max_rad = x;
            }
        }
        self.adapter.coefficients_into(&mut r.coefficients);
        r.updates_dropped = self.updates_dropped;
    }
}

impl Snapshot {
    /// The control period's snapshot with the adaptation's figures: what the supervisor
    /// works on.
    pub fn merged(mut self, r: &AdaptReport) -> Telemetry {
        if self.sweep.is_none() {
            self.sweep = self.sweep_fit.map(|f| f.result());
        }
        Telemetry {
            snapshot: self,
            converged: r.converged,
            revs: r.revs,
            residual_max_rad: r.residual_max_rad,
            coefficients: r.coefficients,
            install: r.install,
            updates_dropped: r.updates_dropped,
        }
    }
}
