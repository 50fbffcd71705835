//! The MRAS decoupler (paper Fig. 6): a bank of harmonic paths, each correlating the
//! model reference error (MRE, the observer's cross-product error ε) with the rotating
//! unit vector of its error harmonic and adapting one complex coefficient.
//!
//! Notation (docs/theory.md §2): a net sensor error whose angle error is
//! `δ(θs) = Im(G·e^{j m θs})` has error phasor `G`. The observer passes it to ε as
//! `H(j m N ω̂)·G`, so the mean of `ε·e^{-j m θ̂s}` is `H·G/(2j)`.

use crate::complex::Cplx;
use crate::config::{AdaptationLaw, Bank, Config, PathKind, MAX_GAIN_PER_RAD, MAX_PATHS};
use crate::observer::ObserverGains;
use crate::transient::TransientGate;
use crate::trig::{max_f32, min_f32, sqrt_inline_f32};
use core::f32::consts::{PI, TAU};

/// |H| floor used for the residual measure when the law itself has none (paper-literal):
/// the same as our default, so that both laws' residuals read alike.
const METRIC_H_FLOOR: f32 = 0.05;
/// The error phasor estimate is low-passed over this much sensor-electrical angle before
/// integration: its ripple (the other paths' harmonics, amplified by 1/|H|) would
/// otherwise drive a limit cycle between paths at low speed (docs/theory.md §3).
pub(crate) const G_WINDOW_RAD: f32 = PI;
/// The residual measure averages over this much sensor-electrical angle (two periods).
const RESIDUAL_WINDOW_RAD: f32 = 2.0 * TAU;
/// Speed and amplitude used by the adaptation are smoothed over this much sensor
/// electrical angle per stage (two stages). Their raw values ripple with the very sensor
/// error being estimated; weighting the correlation with that ripple biases the
/// equilibrium, badly so where |H| is small (docs/theory.md §3).
const SMOOTH_WINDOW_RAD: f32 = TAU;
/// ... but never slower than this in time, so that a reversal is followed near ω = 0.
const SMOOTH_MAX_TAU_S: f32 = 0.1;
/// Samples per path block at least: the paths are updated in turn, one every
/// `BLOCK_SAMPLES / len` samples (0.8 ms at 20 kHz), each with the block sum of its
/// correlation since its last update (docs/performance.md).
pub(crate) const BLOCK_SAMPLES: u32 = 16;
/// Samples between two path updates at least (banks of more than 8 paths): every other
/// sample is free of a path's update, and a survey, which ends on such a sample (the
/// adapter hands over one update per sample), ends.
pub(crate) const MIN_STRIDE: u32 = 2;

/// One path's adaptive state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PathState {
    /// Integral (persistent) coefficient in the path's paper form (Xo+jYo, C+jD, or d_h).
    pub coef: Cplx,
    /// Proportional contribution, recomputed at every update, not persisted.
    pub coef_p: Cplx,
    /// Angle-averaged estimate of the remaining error phasor G (rad, sensor electrical).
    pub residual: Cplx,
    pub coef_at_rev_start: Cplx,
    /// G estimate low-passed over angle before it is integrated (see [`G_WINDOW_RAD`]).
    pub g_filtered: Cplx,
    /// |Δcoef| over the last completed revolution of adaptation, relative to |Z|.
    pub change_last_rev: f32,
    /// The bank's revolution count this path last measured its change at.
    pub rev_seen: u32,
    /// The bank's revolution count when this path last saw its error (|H| ≥
    /// `gates.min_h`); `None` before it first did.
    pub visible_rev: Option<u32>,
}

impl Default for PathState {
    fn default() -> Self {
        Self {
            coef: Cplx::ZERO,
            coef_p: Cplx::ZERO,
            residual: Cplx::ZERO,
            coef_at_rev_start: Cplx::ZERO,
            g_filtered: Cplx::ZERO,
            change_last_rev: 0.0,
            rev_seen: 0,
            visible_rev: None,
        }
    }
}

/// Powers of the reference unit vector, `pw[i] = e^{j i θ̂s}`, for `i` up to the largest
/// error harmonic or |sequence| of any path (16). A power of two long, so that indices
/// masked with [`POWER_MASK`] need no bounds check in the control path.
pub(crate) type Powers = [Cplx; 32];
pub(crate) const POWER_MASK: usize = 31;

/// Coefficient change that moves the error phasor by `-scale·G/|Z|` (first order).
///
/// A residual component `c_k` (relative to the fundamental) gives `G = c_k` for
/// `k = 1+m` and `G = -conj(c_k)` for `k = 1-m`; the X-only C/D form injects
/// `(C+jD)/2` at `k = -1`.
#[inline]
pub(crate) fn coef_delta(kind: PathKind, g: Cplx, scale: f32) -> Cplx {
    match kind {
        PathKind::Offset => g.conj().scale(scale),
        PathKind::AmplitudeQuadrature => g.conj().scale(2.0 * scale),
        PathKind::Harmonic(h) if h > 1 => g.scale(-scale),
        PathKind::Harmonic(_) => g.conj().scale(scale),
    }
}

/// The decoupling vector (eq. 9, 16) as two polynomials in the reference unit vector,
/// `D(θ) = Σ_k pos[k]·u^k + Σ_k neg[k]·ū^k` (`u = e^{jθ}`), evaluated by Horner's scheme:
/// one complex multiply-add per order, no table of powers. Each path's term goes to its
/// order: the offset to `pos[0]`, d_h to `pos[h]` or `neg[|h|]`, and the X-only
/// `C·cos θ + D·sin θ` to `pos[1] = (C - jD)/2` and `neg[1] = (C + jD)/2`.
/// Orders above both degrees hold zero.
///
/// The control period holds one; a new bank is built whole in the adaptation task and
/// handed over in another, so that putting it in force swaps two pointers
/// (`drive::handoff`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Injection {
    layout: Layout,
    /// `coef + coef_p` of each path, as last set.
    coef: [Cplx; MAX_PATHS],
    pos: Orders,
    neg: Orders,
}

/// Orders a path's term goes to: |h| <= 15 (`PathKind::validate`).
const ORDERS: usize = 16;
/// An order masked with it indexes [`Orders`] without a bounds check.
const ORDER_MASK: usize = ORDERS - 1;
/// A polynomial's coefficients, by order.
type Orders = [Cplx; ORDERS];

/// A bank's paths as the polynomials see them: kinds, degrees, and where each path's
/// term goes.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Layout {
    kinds: [PathKind; MAX_PATHS],
    len: usize,
    /// The bank, packed: what a [`BankPlan`] is checked against.
    packed: PackedBank,
    /// Where path i's term goes when its polynomial coefficients are its alone (the
    /// usual case): `pos[s]` for s < 32, `neg[s - 32]` for s < 64, C/D's two for
    /// [`SLOT_CD`]; [`SLOT_SHARED`] where paths share an order and are summed.
    slot: [u8; MAX_PATHS],
    pos_degree: usize,
    neg_degree: usize,
    /// The negative orders fed, bit k for order k, when they are few beside the degree
    /// (the N = 1 bank: 1, 14 and 15): `D` then steps between them by powers of `ū`
    /// instead of through every order. 0: Horner's scheme through all of them.
    neg_sparse: u32,
    /// Those orders, highest first (at most four: more are not sparse), and how many:
    /// read in turn, where finding each by its bit cost the control period 20 cycles.
    neg_orders: [u8; 4],
    neg_count: u8,
}

/// [`Layout::slot`] of a C/D path alone at order 1.
const SLOT_CD: u8 = 64;
/// [`Layout::slot`] of a path sharing an order with another.
const SLOT_SHARED: u8 = u8::MAX;

impl Layout {
    /// No path. All zero bytes, so that a buffer of it costs no flash (`.bss`): its
    /// slots are never read, [`Self::fill`] sets them.
    const EMPTY: Self = Self {
        kinds: [PathKind::Offset; MAX_PATHS],
        len: 0,
        packed: PackedBank::EMPTY,
        slot: [0; MAX_PATHS],
        pos_degree: 0,
        neg_degree: 0,
        neg_sparse: 0,
        neg_orders: [0; 4],
        neg_count: 0,
    };

    /// Kinds, orders and degrees of `paths` (`packed`, the same bank packed), linear in
    /// the paths.
    fn of(paths: &[PathKind], packed: PackedBank) -> Self {
        let mut l = Self::EMPTY;
        l.fill(paths, packed);
        l
    }

    /// [`Self::of`] written in place (a plan's, in the adaptation task: returned whole
    /// and copied twice, it cost as much again).
    fn fill(&mut self, paths: &[PathKind], packed: PackedBank) {
        *self = Self {
            len: paths.len().min(MAX_PATHS),
            packed,
            slot: [SLOT_SHARED; MAX_PATHS],
            ..Self::EMPTY
        };
        let l = self;
        for (k, p) in l.kinds.iter_mut().zip(paths) {
            *k = *p;
        }
        // The orders a path feeds, as indices into `uses`: positive orders 0..32,
        // negative ones 32..64; C/D feeds both of order 1, any other path one order.
        let feeds = |p: PathKind| -> [usize; 2] {
            let order = p.sequence().unsigned_abs() as usize & POWER_MASK;
            match p {
                PathKind::AmplitudeQuadrature => [1, 32 + 1],
                _ if p.sequence() >= 0 => [order; 2],
                _ => [32 + order; 2],
            }
        };
        // One pass counts the orders' users and takes the degrees, the second reads the
        // counts back: each path's orders are derived once.
        let mut uses = [0u8; 64];
        let mut fed = [[0usize; 2]; MAX_PATHS];
        for (&p, f) in l.kinds.iter().zip(fed.iter_mut()).take(l.len) {
            let [a, b] = feeds(p);
            *f = [a, b];
            if let Some(u) = uses.get_mut(a) {
                *u = u.saturating_add(1);
            }
            if b != a {
                if let Some(u) = uses.get_mut(b) {
                    *u = u.saturating_add(1);
                }
            }
            // Orders 32.. are the negative ones; C/D feeds order 1 of both.
            if a < 32 {
                l.pos_degree = l.pos_degree.max(a);
            }
            if b >= 32 {
                l.neg_degree = l.neg_degree.max(b - 32);
                l.neg_sparse |= 1 << ((b - 32) & POWER_MASK);
            }
        }
        // A power of ū by squaring costs about what two orders of Horner's scheme do:
        // worth it where each used order skips more than three on average.
        if 3 * l.neg_sparse.count_ones() as usize >= l.neg_degree {
            l.neg_sparse = 0;
        }
        let mut orders = l.neg_sparse;
        for o in l.neg_orders.iter_mut() {
            if orders == 0 {
                break;
            }
            let k = 31 - orders.leading_zeros();
            *o = k as u8;
            orders &= !(1 << k);
            l.neg_count += 1;
        }
        for (slot, [a, b]) in l.slot.iter_mut().zip(fed).take(l.len) {
            let once = |o: usize| uses.get(o).is_some_and(|&u| u == 1);
            if once(a) && once(b) {
                *slot = if a == b { a as u8 } else { SLOT_CD };
            }
        }
    }

    fn kinds(&self) -> &[PathKind] {
        self.kinds.get(..self.len).unwrap_or(&self.kinds)
    }

    fn top(&self) -> usize {
        self.pos_degree.max(self.neg_degree) & ORDER_MASK
    }
}

/// Another bank for the decoupling vector, worked out against the bank in force where
/// there is time (the adaptation, [`crate::Adapter::plan`]): its layout and which of the
/// old terms each new path keeps. Putting it in force ([`Injection::apply`]) then moves
/// terms only.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BankPlan {
    /// The bank it was worked out from: a plan for another is refused.
    from: PackedBank,
    layout: Layout,
    /// New path i starts at old path `keep[i]`'s term (`u8::MAX`: at zero).
    keep: [u8; MAX_PATHS],
}

impl BankPlan {
    /// From bank `from` to bank `to`: the terms of kinds in both are kept, the others
    /// start at zero.
    pub fn new(from: &[PathKind], to: &[PathKind]) -> Self {
        let mut plan = Self::laid_out(to, Bank::new(to).into());
        plan.keep_from(from, Bank::new(from).into());
        plan
    }

    /// [`Self::new`]'s first half, `to` packed given: its layout (in the adaptation task,
    /// a step of a survey's end of its own).
    pub(crate) fn laid_out(to: &[PathKind], packed: PackedBank) -> Self {
        let mut plan = Self::EMPTY;
        plan.lay_out(to, packed);
        plan
    }

    /// No bank to none.
    pub(crate) const EMPTY: Self = Self {
        from: PackedBank::EMPTY,
        layout: Layout::EMPTY,
        keep: [u8::MAX; MAX_PATHS],
    };

    /// [`Self::laid_out`] in place.
    pub(crate) fn lay_out(&mut self, to: &[PathKind], packed: PackedBank) {
        self.from = PackedBank::EMPTY;
        self.layout.fill(to, packed);
        self.keep = [u8::MAX; MAX_PATHS];
    }

    /// [`Self::new`]'s second half, `from` packed given: which of its terms each path
    /// keeps.
    pub(crate) fn keep_from(&mut self, from: &[PathKind], packed: PackedBank) {
        let mut old_at = [u8::MAX; 32];
        for (i, &k) in from.iter().enumerate().take(MAX_PATHS) {
            if let Some(slot) = old_at.get_mut(PackedBank::code(k) as usize) {
                if *slot == u8::MAX {
                    *slot = i as u8;
                }
            }
        }
        for (k, &kind) in self.keep.iter_mut().zip(self.layout.kinds()) {
            *k = old_at
                .get(PackedBank::code(kind) as usize)
                .copied()
                .unwrap_or(u8::MAX);
        }
        self.from = packed;
    }

    /// The bank this plan puts in force.
    pub fn bank(&self) -> PackedBank {
        self.layout.packed
    }
}

impl Injection {
    /// No path: what a buffer holds before it is given a bank.
    pub const EMPTY: Self = Self {
        layout: Layout::EMPTY,
        coef: [Cplx::ZERO; MAX_PATHS],
        pos: [Cplx::ZERO; ORDERS],
        neg: [Cplx::ZERO; ORDERS],
    };

    /// The bank `paths`, every term zero.
    pub fn new(paths: &[PathKind]) -> Self {
        Self {
            layout: Layout::of(paths, Bank::new(paths).into()),
            ..Self::EMPTY
        }
    }

    /// The bank in force.
    #[inline(always)]
    pub fn bank(&self) -> &PackedBank {
        &self.layout.packed
    }

    /// `change` in force, as the front puts it ([`crate::Front::apply`]): a path's term,
    /// or a new bank (with its plan when there is one for it: the same result, faster).
    pub fn apply(&mut self, change: &Change, plan: Option<&BankPlan>) {
        match *change {
            Change::Term { path, value } => self.set(path as usize, value),
            Change::Bank(b) => self.put_bank(&b, plan),
        }
    }

    /// Bank `b` in force, with `plan` if it was worked out for it from the bank in force
    /// (then only terms move), else worked out here: the same result.
    #[cold]
    #[inline(never)]
    pub(crate) fn put_bank(&mut self, b: &PackedBank, plan: Option<&BankPlan>) {
        let planned = plan.is_some_and(|p| p.bank() == *b && self.install(p));
        if !planned {
            self.rebank(b.unpack().as_slice());
        }
    }

    /// Another bank: the terms of kinds in both are kept, the others start at zero.
    pub(crate) fn rebank(&mut self, paths: &[PathKind]) {
        let plan = BankPlan::new(self.kinds(), paths);
        self.install(&plan);
    }

    /// Put `plan` in force (`false`, nothing changed: it was worked out from another
    /// bank). Only moves terms: it runs in a step of the adaptation task.
    #[inline(never)]
    pub(crate) fn install(&mut self, plan: &BankPlan) -> bool {
        if plan.from != self.layout.packed {
            return false;
        }
        // Indices masked to the arrays' lengths (powers of two) instead of iterators and
        // `get`: their checks were a third of it.
        const PATH_MASK: usize = MAX_PATHS - 1;
        let old = self.coef;
        // Orders above both degrees hold zero: clear up to the larger bank's.
        let top = self.layout.top().max(plan.layout.top()) & ORDER_MASK;
        for k in 0..top + 1 {
            self.pos[k & ORDER_MASK] = Cplx::ZERO;
            self.neg[k & ORDER_MASK] = Cplx::ZERO;
        }
        self.layout = plan.layout;
        let len = self.layout.len.min(MAX_PATHS);
        let mut shared = false;
        for i in 0..MAX_PATHS {
            let j = plan.keep[i] as usize;
            self.coef[i] = Cplx::ZERO;
            if i < len && j < MAX_PATHS {
                shared |= !self.place(i, old[j & PATH_MASK]);
            }
        }
        // Paths sharing an order are summed once every term is in place.
        if shared {
            for i in 0..len {
                self.set(i, self.coef[i & PATH_MASK]);
            }
        }
        true
    }

    /// Path `path`'s term where it goes alone (`false`: it shares its order, and only
    /// the term was stored).
    #[inline(always)]
    fn place(&mut self, path: usize, coef: Cplx) -> bool {
        if path >= MAX_PATHS {
            return true;
        }
        // Masked, not `get`: `install` places every path of a bank.
        let path = path & (MAX_PATHS - 1);
        self.coef[path] = coef;
        let s = self.layout.slot[path] as usize;
        match s {
            0..32 => self.pos[s & ORDER_MASK] = coef,
            32..64 => self.neg[s & ORDER_MASK] = coef,
            64 => {
                self.pos[1] = coef.conj().scale(0.5);
                self.neg[1] = coef.scale(0.5);
            }
            _ => return false,
        }
        true
    }

    pub fn kinds(&self) -> &[PathKind] {
        self.layout.kinds()
    }

    /// Path `path`'s new term: the polynomial coefficients it feeds are summed again over
    /// the paths sharing them (no running sums: nothing drifts over millions of updates).
    /// A path alone at its order is placed inline: the control interrupt puts a term in
    /// force every stride, and the call's frame was most of it.
    #[inline(always)]
    pub(crate) fn set(&mut self, path: usize, coef: Cplx) {
        if !self.place(path, coef) {
            self.set_shared(path);
        }
    }

    /// [`Self::set`] of a path sharing its order, its term stored: the order's sum again.
    #[inline(never)]
    fn set_shared(&mut self, path: usize) {
        let Some(&kind) = self.layout.kinds.get(path) else {
            return;
        };
        let order = kind.sequence().unsigned_abs() as usize & ORDER_MASK;
        match kind {
            PathKind::AmplitudeQuadrature => {
                self.pos[1] = self.sum_at(1, true);
                self.neg[1] = self.sum_at(1, false);
            }
            _ if kind.sequence() >= 0 => self.pos[order] = self.sum_at(order, true),
            _ => self.neg[order] = self.sum_at(order, false),
        }
    }

    /// Σ of the paths' contributions to `pos[order]` (or `neg[order]`).
    fn sum_at(&self, order: usize, positive: bool) -> Cplx {
        let mut sum = Cplx::ZERO;
        for (&kind, &c) in self
            .layout
            .kinds
            .iter()
            .zip(&self.coef)
            .take(self.layout.len)
        {
            let k = kind.sequence();
            sum += match kind {
                PathKind::AmplitudeQuadrature if order == 1 => {
                    if positive {
                        c.conj().scale(0.5)
                    } else {
                        c.scale(0.5)
                    }
                }
                PathKind::AmplitudeQuadrature => Cplx::ZERO,
                _ if k.unsigned_abs() as usize == order && (k >= 0) == positive => c,
                _ => Cplx::ZERO,
            };
        }
        sum
    }

    /// `D(θ)` for `u = e^{jθ}`.
    #[inline(always)]
    pub(crate) fn vector(&self, u: Cplx) -> Cplx {
        // Plain countdowns from a masked degree (an iterator's bounds arithmetic would
        // double the loop's cost); the index below it needs no mask (masked again, the
        // mask stayed in the unrolled loop).
        let mut k = self.layout.pos_degree & ORDER_MASK;
        let mut d = self.pos[k];
        while k > 0 {
            k -= 1;
            d = d * u + self.pos[k];
        }
        if self.layout.neg_sparse != 0 {
            return d + self.sparse_negative(u.conj());
        }
        let mut k = self.layout.neg_degree & ORDER_MASK;
        if k > 0 {
            let v = u.conj();
            let mut n = self.neg[k];
            while k > 1 {
                k -= 1;
                n = n * v + self.neg[k];
            }
            d += n * v;
        }
        d
    }
}

impl Injection {
    /// `Σ_k neg[k]·v^k` over the orders of [`Layout::neg_sparse`] (order 0 is never
    /// negative): Horner's scheme from order to order, a power of `v` for each gap.
    #[inline(always)]
    fn sparse_negative(&self, v: Cplx) -> Cplx {
        let [top, lower @ ..] = self.layout.neg_orders;
        let mut k = top as u32;
        let mut n = self.neg[k as usize & ORDER_MASK];
        for &j in lower
            .iter()
            .take((self.layout.neg_count as usize).saturating_sub(1))
        {
            let j = j as u32;
            n = n * power(v, k - j) + self.neg[j as usize & ORDER_MASK];
            k = j;
        }
        n * power(v, k)
    }
}

/// `b^e` for e ≥ 1, by squaring.
#[inline(always)]
fn power(b: Cplx, e: u32) -> Cplx {
    // r = b·b^(e-1): p runs through b^(2^i) for the bits i of e - 1.
    let (mut r, mut p) = (b, b);
    let mut e = e.saturating_sub(1);
    while e != 0 {
        if e & 1 != 0 {
            r = r * p;
        }
        e >>= 1;
        if e != 0 {
            p = p * p;
        }
    }
    r
}

/// One accepted control period as the adaptation needs it: what the control interrupt
/// hands to the adaptation (a lower-priority task in the firmware, see [`crate::Adapter`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AdaptSample {
    /// The front's period count at this sample (schedules the resulting update).
    pub index: u32,
    /// ε, sensor electrical radians (normalised by |Zd|).
    pub eps_e_rad: f32,
    /// `e^{jθ̂s}` at the prior estimate: the reference the correlation demodulates with.
    pub u: Cplx,
    /// ω̂ as output by the observer (rad/s mechanical).
    pub omega_rad_s: f32,
    /// |Zd| of this sample.
    pub amplitude: f32,
    pub disturbance_nm: f32,
    pub torque_ff_nm: f32,
    /// |Z| at a (re-)acquisition ([`AdaptSample::RESTART`]): the smoothing restarts there.
    pub restart_amplitude: f32,
    pub flags: u8,
}

impl AdaptSample {
    /// The observer is locked ([`crate::Front::is_locked`]).
    pub const LOCKED: u8 = 1;
    /// Manual freeze: measure the residual but do not adapt.
    pub const FROZEN: u8 = 2;
    /// The observer (re-)started on this sample, at the sample's ω̂ (0 at rest): restart
    /// smoothing and blocks first.
    pub const RESTART: u8 = 4;
    /// Publish the convergence report after this sample (the supervisor's snapshot).
    pub const REPORT: u8 = 8;

    #[inline(always)]
    pub fn has(&self, flag: u8) -> bool {
        self.flags & flag != 0
    }
}

/// A change of the decoupling vector and the front's period from which it is in force:
/// a fixed latency after the sample that caused it, so that where the adaptation runs
/// (inline on the host, in a task on the target) does not change a single bit of the
/// result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InjectionUpdate {
    pub apply_at: u32,
    pub change: Change,
}

impl InjectionUpdate {
    /// Periods from `coming` (the index of the period about to run) to the one this is
    /// in force from, with wrapping indices: ≤ 0 when it is due now, < 0 when it was due
    /// earlier (late).
    #[inline(always)]
    pub fn due_in(&self, coming: u32) -> i32 {
        self.apply_at.wrapping_sub(coming) as i32
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Change {
    /// Path `path`'s new term, `coef + coef_p` (path order).
    Term { path: u8, value: Cplx },
    /// A new bank (the survey's, or a record's): the terms of kinds in both banks are
    /// kept, the others start at zero. Later terms index the new bank.
    Bank(PackedBank),
}

/// A [`Bank`] in 11 bytes, 5 bits per kind: it keeps an update at 16 bytes, moved in
/// registers. At 24 bytes every move of an update was a `memcpy` call (~150
/// instructions per adaptation step, measured with `cargo xtask cycles`).
#[derive(Clone, Copy, Debug, Eq)]
pub struct PackedBank {
    /// Path i's code in bits 5i..5i+5, little-endian ([`PackedBank::code`]).
    bits: [u8; PACKED_BYTES],
    len: u8,
}

/// Bits per packed kind: offset, C/D and the 27 harmonic paths (|h| <= 15, h not in
/// 0..=3, `PathKind::validate`) are 29 codes.
const CODE_BITS: usize = 5;
const PACKED_BYTES: usize = (MAX_PATHS * CODE_BITS).div_ceil(8);
/// Marks a kind that no valid bank holds; unpacking ends the bank there.
const NO_KIND: u8 = 31;

const _: () = assert!(PACKED_BYTES == 10, "PackedBank::eq compares ten bytes");

/// Two words, not a `memcmp` call: the control interrupt checks a built bank with it.
impl PartialEq for PackedBank {
    fn eq(&self, o: &Self) -> bool {
        let words = |b: &[u8; PACKED_BYTES]| {
            let [b0, b1, b2, b3, b4, b5, b6, b7, b8, b9] = *b;
            (
                u64::from_le_bytes([b0, b1, b2, b3, b4, b5, b6, b7]),
                u16::from_le_bytes([b8, b9]),
            )
        };
        self.len == o.len && words(&self.bits) == words(&o.bits)
    }
}

impl PackedBank {
    /// No path (what `Bank::new(&[])` packs to).
    pub const EMPTY: Self = Self {
        bits: [0; PACKED_BYTES],
        len: 0,
    };

    /// Offset 0, C/D 1, h = -1..=-15 as 2..=16, h = 4..=15 as 17..=28.
    pub(crate) fn code(k: PathKind) -> u8 {
        match k {
            PathKind::Offset => 0,
            PathKind::AmplitudeQuadrature => 1,
            PathKind::Harmonic(h @ -15..=-1) => (1 - h) as u8,
            PathKind::Harmonic(h @ 4..=15) => (h + 13) as u8,
            PathKind::Harmonic(_) => NO_KIND,
        }
    }

    fn kind(c: u8) -> Option<PathKind> {
        match c {
            0 => Some(PathKind::Offset),
            1 => Some(PathKind::AmplitudeQuadrature),
            2..=16 => Some(PathKind::Harmonic(1 - c as i8)),
            17..=28 => Some(PathKind::Harmonic(c as i8 - 13)),
            _ => None,
        }
    }

    pub fn unpack(&self) -> Bank {
        let mut kinds = [PathKind::Offset; MAX_PATHS];
        let mut len = 0;
        for (i, k) in kinds.iter_mut().enumerate().take(self.len as usize) {
            let bit = i * CODE_BITS;
            let pair = |b: usize| self.bits.get(b).copied().unwrap_or(0) as u16;
            let word = pair(bit / 8) | pair(bit / 8 + 1) << 8;
            match Self::kind((word >> (bit % 8)) as u8 & 0x1F) {
                Some(kind) => *k = kind,
                None => break,
            }
            len = i + 1;
        }
        Bank::new(kinds.get(..len).unwrap_or(&kinds))
    }
}

impl From<Bank> for PackedBank {
    fn from(b: Bank) -> Self {
        // Codes into a bit buffer, whole bytes out as they fill (byte by byte with a
        // shifted pair per code it cost the plan's step about 600 cycles).
        let mut bits = [0; PACKED_BYTES];
        let (mut acc, mut held) = (0u32, 0);
        let mut out = bits.iter_mut();
        for &k in b.as_slice() {
            acc |= (Self::code(k) as u32) << held;
            held += CODE_BITS;
            if held >= 8 {
                if let Some(byte) = out.next() {
                    *byte = acc as u8;
                }
                acc >>= 8;
                held -= 8;
            }
        }
        if let Some(byte) = out.next() {
            *byte = acc as u8;
        }
        Self {
            bits,
            len: b.as_slice().len() as u8,
        }
    }
}

/// Control periods between the sample that completes a block and the period its update
/// is in force: the adaptation task's deadline (0.2 ms at 20 kHz).
pub const UPDATE_LATENCY_PERIODS: u32 = 4;

/// The adaptation law with its constants folded for the control path.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Law {
    Compensated {
        gain_per_rad: f32,
        /// The offset path's, per electrical radian of this sensor.
        offset_gain_per_rad: f32,
        proportional: f32,
    },
    PaperLiteral {
        k1_t_s: f32,
        k2: f32,
    },
}

/// Everything the bank derives once from the configuration and the observer gains.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Constants {
    law: Law,
    /// λ sums of the observer (1/H, [`ObserverGains::inverse_error_transfer`]).
    sigma: [f32; 3],
    /// N·Ts: sensor-electrical angle per sample per rad/s.
    n_t_s: f32,
    inv_n: f32,
    /// Smoothing gain per stride: per rad/s of speed, and its floor (see [`Smoothed`]).
    smooth_per_rad_s: f32,
    smooth_min: f32,
    min_speed_rad_s: f32,
    max_speed_deviation: f32,
    max_disturbance_nm: f32,
    max_torque_nm: f32,
    /// The sweep gate's net torque limit per (rad/s)² of smoothed speed: its limit on
    /// |dω/dt|/(N·ω²) times N·Ĵ; infinite for the paper's law.
    sweep_nm_per_w2: f32,
    /// |H| floor of the compensation, and 1/floor², 1/min_h² to compare |1/H|² with.
    h_floor: f32,
    inv_h_floor2: f32,
    inv_min_h2: f32,
    coefficient_limit: f32,
    /// Angle of one mechanical revolution in sensor-electrical radians (2πN).
    rev_rad: f32,
}

impl Constants {
    fn new(cfg: &Config, gains: &ObserverGains, stride: u32) -> Self {
        let n = cfg.sensor_periods as f32;
        let t_s = cfg.sample_period_s;
        let (law, h_floor) = match cfg.law {
            AdaptationLaw::Compensated {
                gain_per_rad,
                offset_gain_per_mech_rad,
                proportional,
                h_floor,
            } => (
                Law::Compensated {
                    gain_per_rad,
                    offset_gain_per_rad: min_f32(
                        max_f32(offset_gain_per_mech_rad / n, gain_per_rad),
                        MAX_GAIN_PER_RAD,
                    ),
                    proportional,
                },
                h_floor,
            ),
            AdaptationLaw::PaperLiteral { k1_per_s, k2 } => (
                Law::PaperLiteral {
                    k1_t_s: k1_per_s * t_s,
                    k2,
                },
                METRIC_H_FLOOR,
            ),
        };
        let g = &cfg.gates;
        let sweep_nm_per_w2 = match law {
            Law::Compensated { .. } => g.max_sweep_per_rad * n * gains.inertia_kg_m2,
            Law::PaperLiteral { .. } => f32::INFINITY,
        };
        Self {
            law,
            sigma: gains.sigma,
            n_t_s: n * t_s,
            inv_n: 1.0 / n,
            smooth_per_rad_s: stride as f32 * n * t_s * (1.0 / SMOOTH_WINDOW_RAD),
            smooth_min: stride as f32 * t_s * (1.0 / SMOOTH_MAX_TAU_S),
            min_speed_rad_s: g.min_speed_rad_s,
            max_speed_deviation: g.max_speed_deviation,
            max_disturbance_nm: g.max_disturbance_nm,
            max_torque_nm: g.max_accel_rad_s2 * gains.inertia_kg_m2,
            sweep_nm_per_w2,
            h_floor,
            inv_h_floor2: 1.0 / (h_floor * h_floor),
            inv_min_h2: 1.0 / (g.min_h * g.min_h),
            coefficient_limit: cfg.health.coefficient_limit,
            rev_rad: TAU * n,
        }
    }
}

/// Two-stage angle-domain low-pass of ω̂ and |Zd| (see [`SMOOTH_WINDOW_RAD`]), and a
/// one-stage one of the net torque.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Smoothed {
    omega1_rad_s: f32,
    omega_rad_s: f32,
    amplitude1: f32,
    amplitude: f32,
    /// T* + T̂d (N·m), Ĵ·dω/dt: one stage is enough to take out the per-sample noise and
    /// leaves the onset of a ramp a fraction of a period late.
    net_torque_nm: f32,
}

impl Smoothed {
    fn reset(omega_rad_s: f32, amplitude: f32) -> Self {
        Self {
            omega1_rad_s: omega_rad_s,
            omega_rad_s,
            amplitude1: amplitude,
            amplitude,
            net_torque_nm: 0.0,
        }
    }

    #[inline]
    fn update(&mut self, omega_rad_s: f32, amplitude: f32, net_torque_nm: f32, alpha: f32) {
        self.net_torque_nm += (net_torque_nm - self.net_torque_nm) * alpha;
        self.omega1_rad_s += (omega_rad_s - self.omega1_rad_s) * alpha;
        self.amplitude1 += (amplitude - self.amplitude1) * alpha;
        self.omega_rad_s += (self.omega1_rad_s - self.omega_rad_s) * alpha;
        self.amplitude += (self.amplitude1 - self.amplitude) * alpha;
    }
}

/// The paths, adapted in turn: every sample adds `ε·e^{-j m θ̂s}` to each path's block
/// sum (two multiply-adds a path), and every `stride` samples one path, round-robin,
/// turns its block into an update (compensation by 1/H, filtering, integration over the
/// block's angle). It runs on [`AdaptSample`]s, off the control interrupt on the target;
/// the decoupling vector's terms it produces go back as [`InjectionUpdate`]s.
/// The law is integrated over angle, so updating a path with its block every `len`
/// samples gives the dynamics of updating it every sample, at a fraction of the cost
/// (docs/performance.md).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct PathBank {
    pub kinds: [PathKind; MAX_PATHS],
    pub state: [PathState; MAX_PATHS],
    pub len: usize,
    /// Error harmonic m of each path (index into the powers of the reference vector).
    m: [u8; MAX_PATHS],
    /// Σ ε·e^{-j m θ̂s} of each path over the samples since its last update (its block).
    acc: [Cplx; MAX_PATHS],
    /// `pw[i] = e^{j i θ̂s}` of the sample in work, up to the largest m.
    pw: Powers,
    max_m: usize,
    /// m·N as f32: the temporal frequency of the path's error is m·N·ω̂.
    m_n: [f32; MAX_PATHS],
    /// Samples between two path updates, and per path block (`stride · len`).
    stride: u32,
    block: u32,
    inv_block: f32,
    inv_stride: f32,
    /// Samples since the last update (0..stride).
    phase: u32,
    /// The path updated next.
    slot: usize,
    /// Consecutive samples with the gates open (a block counts only if all of it was).
    open_run: u32,
    /// Samples adapted since the last update (for the revolution count).
    adapted_samples: u32,
    /// Σ ω̂, Σ |Zd| and Σ (T* + T̂d) since the last update: the smoothing's input.
    omega_sum: f32,
    amplitude_sum: f32,
    net_torque_sum: f32,
    smooth: Smoothed,
    /// Gate state derived from the smoothed speed at the last update: speed high
    /// enough, and the window ω̂ must stay in (steady speed).
    speed_ok: bool,
    omega_window: [f32; 2],
    /// Whether |ω̂| falls slowly enough to adapt (see `Gates::max_sweep_per_rad`).
    sweep_ok: bool,
    k: Constants,
    /// Sensor-electrical angle adapted over since the last revolution boundary.
    pub angle_this_rev_rad: f32,
    pub revs_adapted: u32,
    /// Keeps the observer's torque transients out of the correlation (our law only).
    transient: TransientGate,
}

impl PathBank {
    /// [`Self::new`] in place: built aside and copied over, a survey round's new bank
    /// cost the adaptation task about 2 300 cycles more (1.6 kB). The price is a second
    /// copy of the builder in flash (1.7 kB): the rustc of today does not build a
    /// returned bank straight into `*self`.
    #[inline(never)]
    /// [`Self::new`] in place, first step: the paths' state cleared. A survey round
    /// builds its bank aside a step a run of the adaptation task; built whole and copied
    /// in, it took more than a 40 kHz control period of the task's time.
    pub fn renew_state(&mut self) {
        self.state = [PathState::default(); MAX_PATHS];
        self.acc = [Cplx::ZERO; MAX_PATHS];
        self.pw = [Cplx::ONE; 32];
    }

    /// [`Self::new`] in place, second step: every other field as it sets it but the
    /// law's constants and the transient gate ([`Self::renew_law`]; the pattern names
    /// each field, so that a field added later must be renewed too).
    pub fn renew_rest(&mut self, cfg: &Config) {
        let Self {
            kinds,
            state: _,
            len,
            m,
            acc: _,
            pw: _,
            max_m,
            m_n,
            stride,
            block,
            inv_block,
            inv_stride,
            phase,
            slot,
            open_run,
            adapted_samples,
            omega_sum,
            amplitude_sum,
            net_torque_sum,
            smooth,
            speed_ok,
            omega_window,
            sweep_ok,
            k: _,
            angle_this_rev_rad,
            revs_adapted,
            transient: _,
        } = self;
        let paths = cfg.paths();
        let (orders, top, freqs) = Self::orders(cfg);
        let (s, b) = Self::strides(paths.len());
        *kinds = cfg.paths;
        *len = paths.len();
        *m = orders;
        *max_m = top;
        *m_n = freqs;
        *stride = s;
        *block = b;
        *inv_block = 1.0 / b as f32;
        *inv_stride = 1.0 / s as f32;
        *phase = 0;
        *slot = 0;
        *open_run = 0;
        *adapted_samples = 0;
        *omega_sum = 0.0;
        *amplitude_sum = 0.0;
        *net_torque_sum = 0.0;
        *smooth = Smoothed::reset(0.0, 1.0);
        *speed_ok = false;
        *omega_window = [0.0; 2];
        *sweep_ok = true;
        *angle_this_rev_rad = 0.0;
        *revs_adapted = 0;
    }

    /// [`Self::new`] in place, last step (after [`Self::renew_rest`]): the law's
    /// constants and the transient gate.
    pub fn renew_law(&mut self, cfg: &Config, gains: &ObserverGains) {
        let compensated = matches!(cfg.law, AdaptationLaw::Compensated { .. });
        self.k = Constants::new(cfg, gains, self.stride);
        self.transient = TransientGate::new(cfg, compensated);
    }

    /// Each path's error harmonic m, the largest, and m·N as f32.
    fn orders(cfg: &Config) -> ([u8; MAX_PATHS], usize, [f32; MAX_PATHS]) {
        let paths = cfg.paths();
        let mut m = [0; MAX_PATHS];
        let max_m = paths
            .iter()
            .map(|p| p.error_harmonic() as usize)
            .max()
            .unwrap_or(0);
        let mut m_n = [0.0; MAX_PATHS];
        for ((mi, fi), p) in m.iter_mut().zip(m_n.iter_mut()).zip(paths) {
            *mi = p.error_harmonic();
            *fi = p.error_harmonic() as f32 * cfg.sensor_periods as f32;
        }
        (m, max_m.min(POWER_MASK), m_n)
    }

    /// Samples between two path updates, and per block, for `len` paths.
    fn strides(len: usize) -> (u32, u32) {
        let stride = (BLOCK_SAMPLES / len.max(1) as u32).max(MIN_STRIDE);
        (stride, stride * len.max(1) as u32)
    }

    /// (Not inlined: built at init and at a record's rebank; a survey round's bank is
    /// built in place, [`Self::renew_state`] and the steps after it.)
    #[inline(never)]
    pub fn new(cfg: &Config, gains: &ObserverGains) -> Self {
        Self::build(cfg, gains)
    }

    #[inline(always)]
    fn build(cfg: &Config, gains: &ObserverGains) -> Self {
        let paths = cfg.paths();
        let (m, max_m, m_n) = Self::orders(cfg);
        let (stride, block) = Self::strides(paths.len());
        Self {
            kinds: cfg.paths,
            state: [PathState::default(); MAX_PATHS],
            len: paths.len(),
            m,
            acc: [Cplx::ZERO; MAX_PATHS],
            pw: [Cplx::ONE; 32],
            max_m,
            m_n,
            stride,
            block,
            inv_block: 1.0 / block as f32,
            inv_stride: 1.0 / stride as f32,
            phase: 0,
            slot: 0,
            open_run: 0,
            adapted_samples: 0,
            omega_sum: 0.0,
            amplitude_sum: 0.0,
            net_torque_sum: 0.0,
            smooth: Smoothed::reset(0.0, 1.0),
            speed_ok: false,
            omega_window: [0.0; 2],
            sweep_ok: true,
            k: Constants::new(cfg, gains, stride),
            angle_this_rev_rad: 0.0,
            revs_adapted: 0,
            transient: TransientGate::new(
                cfg,
                matches!(cfg.law, AdaptationLaw::Compensated { .. }),
            ),
        }
    }

    /// Restart the smoothing at the speed the observer (re)started at (0 at rest, the
    /// measured speed after a flying start) and the blocks.
    pub fn restart(&mut self, omega_rad_s: f32, amplitude: f32) {
        self.smooth = Smoothed::reset(omega_rad_s, amplitude);
        self.transient.reset();
        self.speed_ok = false;
        self.omega_window = [0.0; 2];
        self.sweep_ok = true;
        self.phase = 0;
        self.omega_sum = 0.0;
        self.amplitude_sum = 0.0;
        self.net_torque_sum = 0.0;
        self.adapted_samples = 0;
        self.discard_blocks();
    }

    /// Another bank (`cfg`'s paths): the states of kinds in both are kept, the others
    /// start at zero; the smoothing carries on; the revolution count and the transient
    /// gate start again, as the new paths have yet to converge.
    pub fn rebank(&mut self, cfg: &Config, gains: &ObserverGains, plan: &BankPlan) {
        let mut next = Self::new(cfg, gains);
        next.carry_from(self, plan);
        *self = next;
    }

    /// What a new bank `self` (fresh from [`Self::new`]) keeps of the bank `old` it
    /// replaces by `plan`: the kept paths' states, the smoothing and the gates.
    pub fn carry_from(&mut self, old: &Self, plan: &BankPlan) {
        for (s, &j) in self.state.iter_mut().zip(&plan.keep).take(self.len) {
            if let Some(o) = old.state.get(j as usize) {
                *s = *o;
            }
        }
        self.smooth = old.smooth;
        self.speed_ok = old.speed_ok;
        self.omega_window = old.omega_window;
        self.sweep_ok = old.sweep_ok;
        self.transient = old.transient;
        self.transient.disarm();
    }

    /// Let torque transients close the adaptation's gate (once converged).
    pub fn arm_transient_gate(&mut self) {
        self.transient.arm();
    }

    pub fn transient_gate_armed(&self) -> bool {
        self.transient.is_armed()
    }

    /// Drop the partial block sums (after new coefficients, a re-acquisition ...).
    pub fn discard_blocks(&mut self) {
        self.acc = [Cplx::ZERO; MAX_PATHS];
        self.open_run = 0;
    }

    /// Start from these coefficients (path order; e.g. from flash): fresh path states,
    /// revolution count and blocks.
    pub fn load(&mut self, coefs: impl Iterator<Item = Cplx>) {
        for (s, v) in self.state.iter_mut().zip(coefs) {
            *s = PathState {
                coef: v,
                coef_at_rev_start: v,
                ..Default::default()
            };
        }
        self.revs_adapted = 0;
        self.angle_this_rev_rad = 0.0;
        self.discard_blocks();
    }

    /// One sample: gate and accumulate; every `stride` samples also smooth and update
    /// one path. Returns whether the adaptation is running (gates open, not frozen), and
    /// the path's new decoupling-vector term when one was updated.
    #[inline(always)]
    pub fn step(&mut self, x: &AdaptSample) -> (bool, Option<InjectionUpdate>) {
        if x.has(AdaptSample::RESTART) {
            self.restart(x.omega_rad_s, x.restart_amplitude);
        }
        self.update_powers(x.u);
        let calm = self.transient.step(x.eps_e_rad);
        let k = &self.k;
        self.omega_sum += x.omega_rad_s;
        self.amplitude_sum += x.amplitude;
        self.net_torque_sum += x.torque_ff_nm + x.disturbance_nm;
        let open = x.has(AdaptSample::LOCKED)
            && self.speed_ok
            && self.sweep_ok
            && x.omega_rad_s >= self.omega_window[0]
            && x.omega_rad_s <= self.omega_window[1]
            && libm::fabsf(x.disturbance_nm) <= k.max_disturbance_nm
            && libm::fabsf(x.torque_ff_nm) <= k.max_torque_nm
            && calm
            && self.len > 0;
        if open {
            let eps = self.transient.high_passed(x.eps_e_rad);
            for (a, &m) in self.acc.iter_mut().zip(&self.m).take(self.len) {
                let p = self.pw[m as usize & POWER_MASK];
                a.re += p.re * eps;
                a.im -= p.im * eps;
            }
            self.open_run = self.open_run.saturating_add(1);
        } else {
            self.open_run = 0;
        }
        let adapting = open && !x.has(AdaptSample::FROZEN);
        self.adapted_samples += adapting as u32;
        self.phase += 1;
        let mut update = None;
        if self.phase >= self.stride {
            self.phase = 0;
            update = self.tick(x);
        }
        (adapting, update)
    }

    /// `pw[i] = u^i` up to the largest error harmonic, by complex multiplication.
    #[inline(always)]
    fn update_powers(&mut self, u: Cplx) {
        self.pw[1] = u;
        if let Some(higher) = self.pw.get_mut(2..self.max_m + 1) {
            let mut p = u;
            for v in higher {
                p = p * u;
                *v = p;
            }
        }
    }

    /// Every `stride` samples: smooth ω̂ and |Zd| with their means over the stride,
    /// re-derive the speed gates, count revolutions, update the next path.
    #[inline(always)]
    fn tick(&mut self, x: &AdaptSample) -> Option<InjectionUpdate> {
        let k = &self.k;
        let omega_mean = self.omega_sum * self.inv_stride;
        let amplitude_mean = self.amplitude_sum * self.inv_stride;
        let net_torque_mean = self.net_torque_sum * self.inv_stride;
        self.omega_sum = 0.0;
        self.amplitude_sum = 0.0;
        self.net_torque_sum = 0.0;
        let alpha = min_f32(
            max_f32(libm::fabsf(omega_mean) * k.smooth_per_rad_s, k.smooth_min),
            1.0,
        );
        self.smooth
            .update(omega_mean, amplitude_mean, net_torque_mean, alpha);
        let w_f = self.smooth.omega_rad_s;
        let w_f_abs = libm::fabsf(w_f);
        self.transient
            .set_lowest_harmonic(w_f_abs * k.rev_rad * (1.0 / TAU));
        self.speed_ok = w_f_abs >= k.min_speed_rad_s;
        let dev = k.max_speed_deviation * w_f_abs;
        self.omega_window = [w_f - dev, w_f + dev];
        // Only a slowing |ω̂| closes it (net torque against ω̂f): the observer still
        // answers as at the higher frequency, where |H| is larger, so 1/H(ω̂f) over-
        // compensates; a rising frequency under-compensates, which only slows the
        // adaptation. A disabled gate's infinite limit times ω = 0 is NaN: open too.
        let limit_nm = k.sweep_nm_per_w2 * (w_f * w_f);
        self.sweep_ok = !self.transient.is_armed()
            || self.smooth.net_torque_nm * w_f >= 0.0
            || libm::fabsf(self.smooth.net_torque_nm) <= limit_nm
            || limit_nm.is_nan();
        let d_theta_e = k.n_t_s * w_f_abs;
        self.angle_this_rev_rad += self.adapted_samples as f32 * d_theta_e;
        self.adapted_samples = 0;
        if self.angle_this_rev_rad >= k.rev_rad {
            // At most one revolution per stride at any speed the observer tracks; more
            // would only drop counts, never loop.
            self.angle_this_rev_rad -= k.rev_rad;
            if self.angle_this_rev_rad >= k.rev_rad {
                self.angle_this_rev_rad = 0.0;
            }
            self.revs_adapted = self.revs_adapted.saturating_add(1);
        }
        if self.len == 0 {
            return None;
        }
        let i = self.slot;
        self.slot = if i + 1 >= self.len { 0 } else { i + 1 };
        self.adapt_path(i, x, d_theta_e * self.block as f32);
        self.state.get(i).map(|s| InjectionUpdate {
            apply_at: x.index.wrapping_add(UPDATE_LATENCY_PERIODS),
            change: Change::Term {
                path: i as u8,
                value: s.coef + s.coef_p,
            },
        })
    }

    /// Turn path `i`'s block sum into an update; `block_rad` is the block's angle.
    #[inline(always)]
    fn adapt_path(&mut self, i: usize, x: &AdaptSample, block_rad: f32) {
        let k = self.k;
        let full = self.open_run >= self.block;
        let (Some(s), Some(&kind), Some(&m_n), Some(acc)) = (
            self.state.get_mut(i),
            self.kinds.get(i),
            self.m_n.get(i),
            self.acc.get_mut(i),
        ) else {
            return;
        };
        let sum = *acc;
        *acc = Cplx::ZERO;
        let amplitude = self.smooth.amplitude;
        if s.rev_seen != self.revs_adapted {
            s.rev_seen = self.revs_adapted;
            s.change_last_rev =
                sqrt_inline_f32((s.coef - s.coef_at_rev_start).norm_sqr()) / amplitude;
            s.coef_at_rev_start = s.coef;
        }
        if !full {
            s.coef_p = Cplx::ZERO;
            return;
        }
        // Mean coherent power of the MRE over the block: ε·e^{-j m θ̂s}, mean H·G/(2j).
        let cp = sum.scale(self.inv_block);
        // G = 2j·cp/H, with |H| floored: 2j·cp·(1/H)·min(1, |H|/floor). H includes the
        // high-pass the correlation sees ε through.
        let w_m = m_n * self.smooth.omega_rad_s;
        let r = ObserverGains::inverse_error_transfer_of(k.sigma, w_m)
            * self.transient.inverse_high_pass(w_m);
        let q = r.norm_sqr();
        // Not finite only at ω̂ = 0, which the speed gate excludes unless it is set to 0.
        let visible = q <= k.inv_min_h2 && q < f32::INFINITY;
        if visible {
            s.visible_rev = Some(self.revs_adapted);
            let comp = if q <= k.inv_h_floor2 {
                r.scale(2.0)
            } else {
                r.scale(2.0 / (sqrt_inline_f32(q) * k.h_floor))
            };
            let g_est = cp.mul_j() * comp;
            let g_alpha = min_f32(block_rad * (1.0 / G_WINDOW_RAD), 1.0);
            let r_alpha = min_f32(block_rad * (1.0 / RESIDUAL_WINDOW_RAD), 1.0);
            s.g_filtered = s.g_filtered + (g_est - s.g_filtered).scale(g_alpha);
            s.residual = s.residual + (g_est - s.residual).scale(r_alpha);
        }
        if x.has(AdaptSample::FROZEN) {
            s.coef_p = Cplx::ZERO;
            return;
        }
        match k.law {
            Law::Compensated {
                gain_per_rad,
                offset_gain_per_rad,
                proportional,
            } => {
                if !visible {
                    s.coef_p = Cplx::ZERO;
                    return;
                }
                let gain = if kind == PathKind::Offset {
                    offset_gain_per_rad
                } else {
                    gain_per_rad
                };
                // Integrated over angle: gain per radian (docs/theory.md §3).
                s.coef += coef_delta(kind, s.g_filtered, gain * amplitude * block_rad);
                s.coef_p = if proportional == 0.0 {
                    Cplx::ZERO
                } else {
                    coef_delta(kind, s.g_filtered, proportional * amplitude)
                };
            }
            Law::PaperLiteral { k1_t_s, k2 } => {
                // CPMRE = ε_m · sign(ω̂) · e^{-j m θ̂s}, PI in time (Fig. 6): the block
                // sum integrates, the block mean is the proportional part.
                let c = sum.scale(libm::copysignf(k.inv_n, x.omega_rad_s));
                s.coef += coef_delta(kind, c, k1_t_s * amplitude);
                s.coef_p = coef_delta(kind, c.scale(self.inv_block), k2 * amplitude);
            }
        }
        let limit = k.coefficient_limit * amplitude;
        let a2 = s.coef.norm_sqr();
        if a2 > limit * limit {
            s.coef = s.coef.scale(limit / sqrt_inline_f32(a2));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `pw[k]` for `k ≥ 0`, `conj(pw[-k])` for `k < 0`.
    #[inline]
    fn power(pw: &Powers, k: i8) -> Cplx {
        let p = pw[k.unsigned_abs() as usize & POWER_MASK];
        if k < 0 {
            p.conj()
        } else {
            p
        }
    }

    /// The path's contribution to the decoupling vector, given `pw[i] = e^{j i θ̂s}`.
    #[inline]
    fn injection(kind: PathKind, coef: Cplx, pw: &Powers) -> Cplx {
        match kind {
            PathKind::Offset => coef,
            // C·cos θ̂s + D·sin θ̂s on X only (eq. 9).
            PathKind::AmplitudeQuadrature => {
                Cplx::new(coef.re * pw[1].re + coef.im * pw[1].im, 0.0)
            }
            PathKind::Harmonic(h) => coef * power(pw, h),
        }
    }

    fn powers_of(u: Cplx) -> Powers {
        let mut pw = [Cplx::ONE; 32];
        for i in 1..32 {
            pw[i] = pw[i - 1] * u;
        }
        pw
    }

    /// The straight-line injection equals the per-kind definition, path by path.
    #[test]
    fn injection_vector_matches_the_path_definitions() {
        let kinds = [
            PathKind::Harmonic(-2),
            PathKind::Offset,
            PathKind::Harmonic(5),
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(-15),
        ];
        let mut inj = Injection::new(&kinds);
        let coefs: [Cplx; 5] =
            core::array::from_fn(|i| Cplx::new(0.01 * (i as f32 + 1.0), -0.003 * i as f32));
        for (i, c) in coefs.iter().enumerate() {
            inj.set(i, *c);
        }
        let u = Cplx::new(libm::cosf(0.7), libm::sinf(0.7));
        // Rebanked to a bank with some of the kinds, in another order: the kept terms
        // follow their kinds, the new kind starts at zero.
        let mut other = inj;
        let other_kinds = [kinds[2], PathKind::Harmonic(9), kinds[0]];
        other.rebank(&other_kinds);
        let expect_other = injection(kinds[2], coefs[2], &powers_of(u))
            + injection(kinds[0], coefs[0], &powers_of(u));
        assert!((other.vector(u) - expect_other).abs() < 1e-7);
        assert_eq!(other.kinds(), other_kinds);
        let pw = powers_of(u);
        let mut expect = Cplx::ZERO;
        for (k, c) in kinds.iter().zip(&coefs) {
            expect += injection(*k, *c, &pw);
        }
        let got = inj.vector(u);
        assert!((got - expect).abs() < 1e-7, "{got:?} vs {expect:?}");
    }

    /// Negative orders few beside their degree are stepped between by powers of ū, many
    /// go through Horner's scheme: both equal the sum of the paths' terms at every angle.
    #[test]
    fn sparse_and_dense_negative_orders_agree_with_the_sum() {
        let sparse = [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(-14),
            PathKind::Harmonic(-15),
            PathKind::Harmonic(-6),
        ];
        let dense = [
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(-2),
            PathKind::Harmonic(-3),
            PathKind::Harmonic(-5),
            PathKind::Harmonic(7),
        ];
        for (kinds, is_sparse) in [(&sparse[..], true), (&dense[..], false)] {
            let mut inj = Injection::new(kinds);
            assert_eq!(inj.layout.neg_sparse != 0, is_sparse, "{kinds:?}");
            let coef = |i: usize| Cplx::new(0.02 / (i as f32 + 1.0), 0.011 * i as f32 - 0.02);
            for i in 0..kinds.len() {
                inj.set(i, coef(i));
            }
            for a in 0..360 {
                let th = a as f32 * 0.0175 - 3.1;
                let u = Cplx::new(libm::cosf(th), libm::sinf(th));
                let pw = powers_of(u);
                let expect = kinds
                    .iter()
                    .enumerate()
                    .fold(Cplx::ZERO, |s, (i, &k)| s + injection(k, coef(i), &pw));
                let got = inj.vector(u);
                assert!(
                    (got - expect).abs() < 2e-7,
                    "{kinds:?} at {th}: {got:?} vs {expect:?}"
                );
            }
        }
        for e in 1..32 {
            let u = Cplx::new(libm::cosf(0.3), libm::sinf(0.3));
            let expect = powers_of(u)[e as usize];
            assert!((super::power(u, e) - expect).abs() < 1e-6, "u^{e}");
        }
    }

    /// A bank renewed in place, in its three steps, for another configuration is the bank
    /// built new for it, whatever it held before (it had adapted: its state is not zero).
    #[test]
    fn a_bank_renewed_in_place_is_the_bank_built_new() {
        let first = crate::Config::default();
        let gains = |c: &crate::Config| {
            ObserverGains::from_eigenvalues(c.observer.eigenvalues_hz, c.observer.inertia_kg_m2)
        };
        let mut bank = PathBank::new(&first, &gains(&first));
        let x = AdaptSample {
            flags: AdaptSample::LOCKED,
            u: Cplx::new(0.6, 0.8),
            eps_e_rad: 0.01,
            omega_rad_s: 100.0,
            amplitude: 1.0,
            ..Default::default()
        };
        for i in 0..5000 {
            bank.step(&AdaptSample { index: i, ..x });
        }
        assert_ne!(bank, PathBank::new(&first, &gains(&first)));
        let mut other = first;
        other.sensor_periods = 1;
        other
            .set_paths(&[
                PathKind::Offset,
                PathKind::AmplitudeQuadrature,
                PathKind::Harmonic(7),
                PathKind::Harmonic(-14),
            ])
            .unwrap();
        other.law = AdaptationLaw::PaperLiteral {
            k1_per_s: 20.0,
            k2: 0.5,
        };
        bank.renew_state();
        bank.renew_rest(&other);
        bank.renew_law(&other, &gains(&other));
        assert_eq!(bank, PathBank::new(&other, &gains(&other)));
    }

    /// A bank grown to the full 16 paths of an N = 1 survey and shrunk again: each path
    /// keeps its term through both rebanks, the new ones start at zero, and the vector
    /// reaches the highest orders of either sign.
    #[test]
    fn a_full_bank_rebanks_with_its_terms() {
        let mut full = [PathKind::Offset; MAX_PATHS];
        full[1] = PathKind::AmplitudeQuadrature;
        for (k, h) in full[2..14].iter_mut().zip(4..) {
            *k = PathKind::Harmonic(h);
        }
        full[14] = PathKind::Harmonic(-14);
        full[15] = PathKind::Harmonic(-15);
        let coef = |k: PathKind| Cplx::new(1e-3 * k.sequence() as f32, 2e-3);
        let expect = |kinds: &[PathKind], u: Cplx| {
            let pw = powers_of(u);
            kinds
                .iter()
                .fold(Cplx::ZERO, |s, &k| s + injection(k, coef(k), &pw))
        };
        let u = Cplx::new(libm::cosf(-2.1), libm::sinf(-2.1));
        let first: [PathKind; 4] = [full[15], full[0], full[13], full[1]];
        let mut inj = Injection::new(&first);
        for (i, &k) in first.iter().enumerate() {
            inj.set(i, coef(k));
        }
        inj.rebank(&full);
        let kept = expect(&first, u);
        assert!((inj.vector(u) - kept).abs() < 1e-6);
        for (i, &k) in full.iter().enumerate() {
            inj.set(i, coef(k));
        }
        assert!((inj.vector(u) - expect(&full, u)).abs() < 1e-6);
        let last = [full[14], full[2], full[1]];
        inj.rebank(&last);
        assert_eq!(inj.kinds(), last);
        assert!((inj.vector(u) - expect(&last, u)).abs() < 1e-6);
    }

    /// A plan made from the bank in force puts in force what a new injection of the
    /// new bank with the kept terms holds, bit for bit (also where paths share an
    /// order); a plan made from another bank is refused and changes nothing.
    #[test]
    fn a_bank_plan_installs_the_kept_terms_and_only_on_its_bank() {
        let coef = |k: PathKind| Cplx::new(1e-3 * k.sequence() as f32 + 5e-4, -2e-3);
        let a = [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(5),
            PathKind::Harmonic(-2),
        ];
        let b = [
            PathKind::Harmonic(-2),
            PathKind::Offset,
            PathKind::Harmonic(-1),
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(9),
            PathKind::Harmonic(-15),
        ];
        let mut inj = Injection::new(&a);
        for (i, &k) in a.iter().enumerate() {
            inj.set(i, coef(k));
        }
        let mut want = Injection::new(&b);
        for (i, &k) in b.iter().enumerate() {
            if a.contains(&k) {
                want.set(i, coef(k));
            }
        }
        let before = inj;
        assert!(!inj.install(&BankPlan::new(&b, &a)));
        assert_eq!(inj, before);
        let plan = BankPlan::new(&a, &b);
        assert_eq!(plan.bank(), Bank::new(&b).into());
        assert!(inj.install(&plan));
        assert_eq!(inj, want);
        // Back to the first bank (h = 5 starts at zero): the orders only the larger one
        // used are zero again.
        let mut back = Injection::new(&a);
        for (i, &k) in a.iter().enumerate() {
            if b.contains(&k) {
                back.set(i, coef(k));
            }
        }
        assert!(inj.install(&BankPlan::new(&b, &a)));
        assert_eq!(inj, back);
    }

    /// Every kind a bank can hold survives packing for the update queue, and an update
    /// stays 16 bytes.
    #[test]
    fn a_packed_bank_unpacks_to_itself() {
        let kinds = [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(15),
            PathKind::Harmonic(-1),
            PathKind::Harmonic(-15),
        ];
        let bank = Bank::new(&kinds);
        assert_eq!(PackedBank::from(bank).unpack(), bank);
        // Every valid kind, in a full bank, at every place.
        let all: heapless::Vec<PathKind, 32> = [PathKind::Offset, PathKind::AmplitudeQuadrature]
            .into_iter()
            .chain((-15..=15).map(PathKind::Harmonic))
            .filter(|k| k.validate().is_ok())
            .collect();
        assert_eq!(all.len(), 29);
        for start in 0..all.len() {
            let kinds: heapless::Vec<PathKind, MAX_PATHS> = all
                .iter()
                .cycle()
                .skip(start)
                .take(MAX_PATHS)
                .copied()
                .collect();
            let bank = Bank::new(&kinds);
            assert_eq!(PackedBank::from(bank).unpack(), bank);
        }
        assert_eq!(PackedBank::from(Bank::new(&[])).unpack(), Bank::new(&[]));
        assert_eq!(core::mem::size_of::<InjectionUpdate>(), 16);
    }

    /// Paths sharing an order (h = -1 beside C/D, twice h = 3) sum into it.
    #[test]
    fn paths_sharing_an_order_add_up() {
        let kinds = [
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(-1),
            PathKind::Harmonic(3),
            PathKind::Harmonic(3),
            PathKind::Harmonic(5),
        ];
        let mut inj = Injection::new(&kinds);
        assert_eq!(
            inj.layout.slot[..5],
            [SLOT_SHARED, SLOT_SHARED, SLOT_SHARED, SLOT_SHARED, 5]
        );
        let coefs: [Cplx; 5] = core::array::from_fn(|i| Cplx::new(0.02 * i as f32 + 0.01, 0.005));
        for (i, c) in coefs.iter().enumerate() {
            inj.set(i, *c);
        }
        let u = Cplx::new(libm::cosf(-1.1), libm::sinf(-1.1));
        let pw = powers_of(u);
        let expect = kinds
            .iter()
            .zip(&coefs)
            .fold(Cplx::ZERO, |a, (k, c)| a + injection(*k, *c, &pw));
        assert!((inj.vector(u) - expect).abs() < 1e-6);
    }

    /// The angle error of `e^{jθ} + c_k e^{jkθ}` at θ, to first order, is Im(G e^{jmθ}):
    /// check the sign convention of `coef_delta` by finite differences on the real angle.
    #[test]
    fn negative_powers_are_conjugates() {
        let u = Cplx::new(0.6, 0.8);
        let mut pw = [Cplx::ONE; 32];
        pw[1] = u;
        pw[2] = u * u;
        assert_eq!(power(&pw, -2), (u * u).conj());
        assert_eq!(power(&pw, 2), u * u);
        assert_eq!(power(&pw, 0), Cplx::ONE);
    }

    #[test]
    fn coef_delta_reduces_the_error_phasor() {
        let pw_at = |th: f32| -> Powers {
            let u = Cplx::new(libm::cosf(th), libm::sinf(th));
            powers_of(u)
        };
        for kind in [
            PathKind::Offset,
            PathKind::AmplitudeQuadrature,
            PathKind::Harmonic(4),
            PathKind::Harmonic(-2),
        ] {
            let m = kind.error_harmonic() as i32;
            // Start from a coefficient, measure G by projecting the angle error.
            let g_of = |coef: Cplx| -> Cplx {
                let mut acc = Cplx::ZERO;
                let n = 720;
                for i in 0..n {
                    let th = TAU * i as f32 / n as f32;
                    let pw = pw_at(th);
                    let z = pw[1] + injection(kind, coef, &pw);
                    let err = libm::atan2f(
                        z.im * pw[1].re - z.re * pw[1].im,
                        z.re * pw[1].re + z.im * pw[1].im,
                    );
                    acc += power(&pw, -m as i8).scale(err);
                }
                // δ = Im(G e^{jmθ}) ⇒ mean(δ e^{-jmθ}) = G/(2j) ⇒ G = 2j·mean.
                acc.scale(2.0 / n as f32).mul_j()
            };
            let c0 = Cplx::new(0.02, -0.01);
            let g0 = g_of(c0);
            let c1 = c0 + coef_delta(kind, g0, 0.5);
            let g1 = g_of(c1);
            let ratio = g1.abs() / g0.abs();
            assert!((ratio - 0.5).abs() < 0.02, "{kind:?}: |G| ratio {ratio}");
        }
    }
}
