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

use crate::handoff::Sender;
use crate::telemetry::{Install, InstallAck, Snapshot, Telemetry};
use mras::{
    AdaptSample, Adapter, Bank, BankPlan, Change, Coefficients, ConfigError, Cplx, InjectionUpdate,
    MAX_PATHS, UPDATE_LATENCY_PERIODS,
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

/// The adaptation task's state.
#[derive(Clone, Debug)]
pub struct AdaptationTask {
    adapter: Adapter,
    report: AdaptReport,
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
        let adapter = Adapter::new(cfg)?;
        let mut a = Self {
            report: AdaptReport::EMPTY,
            adapter,
            last_index: 0,
            owed: Owed::NONE,
            updates_dropped: 0,
        };
        a.measure();
        Ok(a)
    }

    /// One handed-over sample; its update, if one is due, goes to `updates`, and a new
    /// bank's plan to `plans` ahead of it.
    pub fn step(
        &mut self,
        s: &AdaptSample,
        updates: &mut impl Sender<InjectionUpdate>,
        plans: &mut impl Sender<BankPlan>,
    ) {
        self.last_index = s.index;
        let (_, update) = self.adapter.step(s);
        if let Some(u) = update {
            if matches!(u.change, Change::Bank(_)) {
                self.send_plan(plans);
            }
            self.send(u, updates);
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
        plans: &mut impl Sender<BankPlan>,
    ) {
        let before = Bank::new(self.adapter.config().paths());
        let accepted = self.adapter.set_coefficients(&i.coefficients).is_ok();
        if accepted {
            let apply_at = self.last_index.wrapping_add(UPDATE_LATENCY_PERIODS);
            // A record's bank from the data differs from the first stage in use: the
            // bank first (the front follows the adapter's every change), then every term.
            let bank = Bank::new(self.adapter.config().paths());
            if bank != before {
                self.send_plan(plans);
                let change = Change::Bank(bank.into());
                self.send(InjectionUpdate { apply_at, change }, updates);
            }
            for (path, (_, value)) in i.coefficients.iter().enumerate() {
                let change = Change::Term {
                    path: path as u8,
                    value,
                };
                self.send(InjectionUpdate { apply_at, change }, updates);
            }
        }
        self.report.install = Some(InstallAck {
            generation: i.generation,
            accepted,
        });
        self.measure();
    }

    /// The plan of the bank the adapter just changed to, if it made one. A plan the
    /// queue cannot take is dropped: the control period then works the bank out itself.
    fn send_plan(&mut self, plans: &mut impl Sender<BankPlan>) {
        if let Some(p) = self.adapter.take_plan() {
            let _ = plans.send(p);
        }
    }

    /// Queue `u` behind whatever is owed, or owe it.
    fn send(&mut self, u: InjectionUpdate, updates: &mut impl Sender<InjectionUpdate>) {
        let refused = match self.send_owed(updates) {
            true => updates.send(u).err(),
            false => Some(u),
        };
        if let Some(u) = refused {
            self.updates_dropped = self.updates_dropped.saturating_add(1);
            self.owe(u);
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
    pub(crate) fn send_owed(&mut self, updates: &mut impl Sender<InjectionUpdate>) -> bool {
        let owed = &mut self.owed;
        if let Some(b) = owed.bank {
            if updates.send(b).is_err() {
                return false;
            }
            owed.bank = None;
        }
        for k in 0..MAX_PATHS {
            if owed.paths == 0 {
                break;
            }
            let i = (owed.next + k) % MAX_PATHS;
            let Some(&(apply_at, value)) = owed.terms.get(i) else {
                break;
            };
            if owed.paths & (1 << i) == 0 {
                continue;
            }
            let change = Change::Term {
                path: i as u8,
                value,
            };
            if updates.send(InjectionUpdate { apply_at, change }).is_err() {
                owed.next = i;
                return false;
            }
            owed.paths &= !(1 << i);
        }
        owed.paths == 0
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

    fn measure(&mut self) {
        let conv = self.adapter.convergence();
        self.report = AdaptReport {
            converged: conv.converged,
            revs: conv.revs_adapted,
            residual_max_rad: conv
                .residual_rad
                .iter()
                .take(conv.len as usize)
                .fold(0.0f32, |a, b| a.max(*b)),
            coefficients: self.adapter.coefficients(),
            install: self.report.install,
            updates_dropped: self.updates_dropped,
        };
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
