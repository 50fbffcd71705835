//! Plain snapshots for persistence and streaming: coefficients and convergence.

use crate::complex::Cplx;
use crate::config::{PathKind, MAX_PATHS};

/// One path's coefficient in the paper's named form.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PaperForm {
    /// Offset decoupling vector (eq. 6-7).
    Offset { xo: f32, yo: f32 },
    /// X-only amplitude/quadrature term C·cos θs + D·sin θs (eq. 9-11, 14-15).
    AmplitudeQuadrature { c: f32, d: f32 },
    /// Harmonic h: E + jF with decoupling `-(E - jF)·e^{j h θs}` (eq. 16-20).
    Harmonic { h: i8, e: f32, f: f32 },
}

/// The adaptive coefficients of every path, in configuration order.
///
/// Values are in scaled sensor units (nominal amplitude 1): offset `Xo + jYo`,
/// C/D path `C + jD`, harmonic path `d_h` with decoupling term `d_h·e^{j h θ̂s}`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coefficients {
    pub(crate) kinds: [PathKind; MAX_PATHS],
    pub(crate) values: [Cplx; MAX_PATHS],
    pub(crate) len: u8,
}

impl Coefficients {
    /// No paths: what a snapshot carries before the adaptation has reported.
    pub const EMPTY: Self = Self {
        kinds: [PathKind::Offset; MAX_PATHS],
        values: [Cplx::ZERO; MAX_PATHS],
        len: 0,
    };

    /// All-zero coefficients for a path list (at most [`MAX_PATHS`] are kept).
    pub fn zeros(paths: &[PathKind]) -> Self {
        let mut c = Self::EMPTY;
        c.set_kinds(paths);
        c
    }

    /// The first [`MAX_PATHS`] of `paths` as the kinds (the values stay).
    pub(crate) fn set_kinds(&mut self, paths: &[PathKind]) {
        let len = paths.len().min(MAX_PATHS);
        for (k, p) in self.kinds.iter_mut().zip(paths) {
            *k = *p;
        }
        for k in self.kinds.iter_mut().skip(len) {
            *k = PathKind::Offset;
        }
        self.len = len as u8;
    }

    /// The paths' kinds, in path order.
    pub fn kinds(&self) -> &[PathKind] {
        self.kinds.get(..self.len()).unwrap_or(&self.kinds)
    }

    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    pub fn iter(&self) -> impl Iterator<Item = (PathKind, Cplx)> + '_ {
        self.kinds
            .iter()
            .copied()
            .zip(self.values.iter().copied())
            .take(self.len())
    }

    pub fn get(&self, kind: PathKind) -> Option<Cplx> {
        self.iter().find(|(k, _)| *k == kind).map(|(_, v)| v)
    }

    /// Set one path's value; false if the path is not in this snapshot.
    pub fn set(&mut self, kind: PathKind, value: Cplx) -> bool {
        match self.kinds[..self.len()].iter().position(|k| *k == kind) {
            Some(i) => {
                self.values[i] = value;
                true
            }
            None => false,
        }
    }

    /// A path's value in the paper's named form.
    pub fn paper_form(&self, kind: PathKind) -> Option<PaperForm> {
        self.get(kind).map(|v| match kind {
            PathKind::Offset => PaperForm::Offset { xo: v.re, yo: v.im },
            PathKind::AmplitudeQuadrature => PaperForm::AmplitudeQuadrature { c: v.re, d: v.im },
            // -(E - jF) = d_h  ⇒  E = -Re d_h, F = Im d_h.
            PathKind::Harmonic(h) => PaperForm::Harmonic {
                h,
                e: -v.re,
                f: v.im,
            },
        })
    }
}

/// Why a coefficient snapshot was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CoefficientsError {
    /// The snapshot's paths differ from the configuration's (count, kind or order).
    PathMismatch,
    /// A value is NaN/inf or beyond `health.coefficient_limit · health.amplitude_max`.
    OutOfRange,
}

/// Convergence measures, one entry per path (configuration order).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Convergence {
    /// |angle-averaged error phasor| still seen by each path (rad, sensor electrical).
    pub residual_rad: [f32; MAX_PATHS],
    /// |coefficient change| over the last revolution of adaptation, relative to |Z|.
    pub change_per_rev: [f32; MAX_PATHS],
    pub len: u8,
    /// Mechanical revolutions of adaptation so far.
    pub revs_adapted: u32,
    /// Bit i: path i has not seen its error in this or the previous revolution of
    /// adaptation (|H| below `gates.min_h` at this speed), so its residual and change
    /// say nothing.
    pub unseen_paths: u16,
    /// `revs_adapted >= min_revs`, no unseen path, and every residual and change below
    /// its threshold (`ConvergenceConfig`).
    pub converged: bool,
}

impl Convergence {
    /// No path measured.
    pub const EMPTY: Self = Self {
        residual_rad: [0.0; MAX_PATHS],
        change_per_rev: [0.0; MAX_PATHS],
        len: 0,
        revs_adapted: 0,
        unseen_paths: 0,
        converged: false,
    };
}

// A bit of `Convergence::unseen_paths` per path.
const _: () = assert!(MAX_PATHS <= u16::BITS as usize);
