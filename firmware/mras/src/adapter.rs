//! The MRAS adaptation (paper Fig. 6) as its own object: it consumes the
//! [`AdaptSample`]s the [`crate::Front`] leaves, and produces the decoupling vector's
//! [`InjectionUpdate`]s and the convergence measures. On the target it runs in a task
//! below the control interrupt; [`crate::Tracker`] runs it inline.

use crate::coefficients::{CoefficientsError, Convergence};
use crate::config::{Config, ConfigError};
use crate::decoupler::{AdaptSample, InjectionUpdate, PathBank};
use crate::observer::ObserverGains;
use crate::{Coefficients, MAX_PATHS};

#[derive(Clone, Debug)]
pub struct Adapter {
    bank: PathBank,
    cfg: Config,
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
        })
    }

    /// One accepted sample, in the order the front produced them. Returns whether the
    /// adaptation ran on it (gates open, not frozen) and the update of the path whose
    /// block it completed, if any.
    #[inline]
    pub fn step(&mut self, s: &AdaptSample) -> (bool, Option<InjectionUpdate>) {
        let revs = self.bank.revs_adapted;
        let out = self.bank.step(s);
        // Once a revolution until armed: a converged bank arms the transient gate.
        if self.bank.revs_adapted != revs
            && !self.bank.transient_gate_armed()
            && self.convergence().converged
        {
            self.bank.arm_transient_gate();
        }
        out
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
    /// match the configuration exactly and every value is finite and within the
    /// coefficient limit. The front's decoupling vector is the caller's to load
    /// ([`crate::Front::load_injection`]).
    pub fn set_coefficients(&mut self, c: &Coefficients) -> Result<(), CoefficientsError> {
        if !c.kinds.iter().take(c.len()).eq(self.cfg.paths().iter()) {
            return Err(CoefficientsError::PathMismatch);
        }
        let limit = self.cfg.health.coefficient_limit * self.cfg.health.amplitude_max;
        if c.iter().any(|(_, v)| !v.is_finite() || v.abs() > limit) {
            return Err(CoefficientsError::OutOfRange);
        }
        self.bank.load(c.iter().map(|(_, v)| v));
        Ok(())
    }

    /// Convergence measures and the `converged` judgement.
    pub fn convergence(&self) -> Convergence {
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
