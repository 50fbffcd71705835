//! The MRAS adaptation's side of the drive: a task below the control period.
//!
//! The control period ([`crate::control::ControlPeriod::step`]) hands every accepted
//! sample over ([`crate::control::ControlPeriod::handoff`]); [`AdaptationTask::step`] turns them into
//! the decoupling vector's updates, which go back through
//! [`crate::control::ControlPeriod::apply`], in force a fixed latency after their sample
//! ([`mras::UPDATE_LATENCY_PERIODS`]). The firmware queues both ways between its control
//! interrupt and its adaptation task; hil-sim runs the task right after each period, as
//! the firmware's scheduler does, so both compute the same bits.
//!
//! The convergence measures and coefficients the supervisor needs are computed here,
//! once per snapshot ([`mras::AdaptSample::REPORT`]), not in the control interrupt.

use crate::telemetry::{Install, InstallAck, Snapshot, Telemetry};
use mras::{AdaptSample, Adapter, Bank, Change, Coefficients, ConfigError, InjectionUpdate};

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
}

impl AdaptReport {
    /// Nothing measured yet.
    pub const EMPTY: Self = Self {
        converged: false,
        revs: 0,
        residual_max_rad: f32::INFINITY,
        coefficients: Coefficients::EMPTY,
        install: None,
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
    /// The period of the last sample adapted on: installs are in force from the next.
    last_index: u32,
}

impl AdaptationTask {
    pub fn new(cfg: &mras::Config) -> Result<Self, ConfigError> {
        let adapter = Adapter::new(cfg)?;
        let mut a = Self {
            report: AdaptReport::EMPTY,
            adapter,
            last_index: 0,
        };
        a.measure();
        Ok(a)
    }

    /// One handed-over sample; returns the decoupling vector's update, if one is due.
    pub fn step(&mut self, s: &AdaptSample) -> Option<InjectionUpdate> {
        self.last_index = s.index;
        let (_, update) = self.adapter.step(s);
        if s.has(AdaptSample::REPORT) {
            self.measure();
        }
        update
    }

    /// Coefficients loaded from flash: validated by the core; if accepted, the bank and
    /// every path's term go to the control period through `send`, in force at once.
    pub fn install(&mut self, i: &Install, mut send: impl FnMut(InjectionUpdate)) {
        let before = Bank::new(self.adapter.config().paths());
        let accepted = self.adapter.set_coefficients(&i.coefficients).is_ok();
        if accepted {
            // A record's bank from the data differs from the first stage in use: the
            // bank first (the front follows the adapter's every change), then every term.
            let bank = Bank::new(self.adapter.config().paths());
            if bank != before {
                send(InjectionUpdate {
                    apply_at: self.last_index,
                    change: Change::Bank(bank.into()),
                });
            }
            for (path, (_, value)) in i.coefficients.iter().enumerate() {
                send(InjectionUpdate {
                    apply_at: self.last_index,
                    change: Change::Term {
                        path: path as u8,
                        value,
                    },
                });
            }
        }
        self.report.install = Some(InstallAck {
            generation: i.generation,
            accepted,
        });
        self.measure();
    }

    /// The report as of the last snapshot sample (or install).
    pub fn report(&self) -> &AdaptReport {
        &self.report
    }

    pub fn adapter(&self) -> &Adapter {
        &self.adapter
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
        };
    }
}

impl Snapshot {
    /// The control period's snapshot with the adaptation's figures: what the supervisor
    /// works on.
    pub fn merged(self, r: &AdaptReport) -> Telemetry {
        Telemetry {
            snapshot: self,
            converged: r.converged,
            revs: r.revs,
            residual_max_rad: r.residual_max_rad,
            coefficients: r.coefficients,
            install: r.install,
        }
    }
}
