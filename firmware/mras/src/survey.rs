//! The sensor's error spectrum, measured before adaptation, and a path bank given to the
//! harmonics that carry error.
//!
//! A bank nulls only the error harmonics it has paths for (paper §V.B). A fixed bank
//! (the default covers m = 1..7) leaves a real sensor's higher harmonics untouched, and
//! spends paths on harmonics that a given sensor does not have. Running the observer with
//! adaptation frozen, ε at sensor harmonic m is the sensor's angle error e_m seen
//! through the observer, ε_m = H(j·m·ω̂s)·e_m (`ObserverGains::error_transfer`), so
//! e_m = ε_m / H: a DFT of ε against θ̂s over whole sensor periods measures the
//! spectrum the bank has to cover.

use crate::complex::Cplx;
use crate::config::{Bank, PathKind, MAX_PATHS};
use crate::decoupler::PackedBank;
use crate::observer::ObserverGains;
use crate::trig::sqrt_f32;

/// Error harmonics m = 1..=`SURVEY_HARMONICS` of θs are measured; a path exists for each
/// (m = 16 is the largest a path reaches: h = -15).
pub const SURVEY_HARMONICS: usize = 16;
/// Whole sensor periods the survey covers: the noise floor from four DFT bins' worth of
/// samples per harmonic, and leakage from a fractional period under 1/4 of a bin.
pub const SURVEY_PERIODS: f32 = 4.0;
/// Harmonics under this share of the largest get no path: what the observer follows of
/// the largest phase-modulates its neighbours, by about 1 % of it (docs/theory.md §8).
pub const MIN_SHARE: f32 = 0.01;
/// The first stage of a bank from the data. Every sensor has an offset and an
/// amplitude/quadrature error, and at the size they come in their products put error
/// into every harmonic of the angle: they adapt first, and the survey measures what
/// remains.
pub const FIRST_STAGE: [PathKind; 2] = [PathKind::Offset, PathKind::AmplitudeQuadrature];
/// Mechanical revolutions the first stage may adapt before the survey starts anyway.
pub const FIRST_STAGE_MAX_REVS: u32 = 20;

/// Accumulates ε against θ̂s while the observer tracks with adaptation frozen.
#[derive(Clone, Debug)]
pub struct ErrorSurvey {
    /// Σ ε·e^{-j m θ̂s}, m = 1..=16.
    sums: [Cplx; SURVEY_HARMONICS],
    /// Σ ε² and Σ ω̂s (sensor electrical, rad/s) over the samples.
    eps2_sum: f32,
    omega_e_sum: f32,
    samples: u32,
    /// θ̂s advance over the samples (rad, signed): whole sensor periods make the DFT exact.
    advance_rad: f32,
    /// e^{jθ̂s} of the previous sample (`ZERO`: none yet).
    last_u: Cplx,
}

/// What the survey measured: the sensor's angle error per harmonic m of θs (rad,
/// sensor electrical; index m - 1) and the noise floor a harmonic must clear.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ErrorSpectrum {
    pub amplitude_rad: [f32; SURVEY_HARMONICS],
    /// Four times the DFT's noise per bin, from the power ε has beyond the harmonics.
    /// Flat in m: sensor noise reaches ε through the same H as the error does, and ε's
    /// noise power is the sensor's (H ≈ 1 over most of the band, the observer's
    /// bandwidth being far below the sample rate).
    pub floor_rad: f32,
    /// Sensor periods the survey covered.
    pub periods: f32,
}

impl Default for ErrorSurvey {
    fn default() -> Self {
        Self {
            sums: [Cplx::ZERO; SURVEY_HARMONICS],
            eps2_sum: 0.0,
            omega_e_sum: 0.0,
            samples: 0,
            advance_rad: 0.0,
            last_u: Cplx::ZERO,
        }
    }
}

impl ErrorSurvey {
    /// One tracked sample: `u` = e^{jθ̂s} (the reference the paths demodulate with, as
    /// [`crate::AdaptSample::u`]), ε (rad) and ω̂s (rad/s, sensor electrical, i.e.
    /// N·ω̂rm).
    pub fn add(&mut self, u: Cplx, eps_rad: f32, omega_e_rad_s: f32) {
        let finite = [u.re, u.im, eps_rad, omega_e_rad_s];
        if !finite.iter().all(|v| v.is_finite()) {
            return;
        }
        if self.last_u != Cplx::ZERO {
            // The step from the previous sample: arg(u·conj(last)).
            let d = u * self.last_u.conj();
            self.advance_rad += libm::atan2f(d.im, d.re);
        }
        self.last_u = u;
        // e^{-j m θ} by repeated multiplication: one rotation per harmonic.
        let step = u.conj();
        let mut rot = step;
        for sum in &mut self.sums {
            *sum += rot.scale(eps_rad);
            rot = rot * step;
        }
        self.eps2_sum += eps_rad * eps_rad;
        self.omega_e_sum += omega_e_rad_s;
        self.samples += 1;
    }

    /// Sensor periods covered so far (θ̂s advance / 2π, unsigned).
    pub fn periods(&self) -> f32 {
        libm::fabsf(self.advance_rad) / core::f32::consts::TAU
    }

    /// The spectrum, the observer's transfer undone at the mean speed; `None` before a
    /// sensor period or at standstill.
    #[inline(never)]
    pub fn spectrum(&self, gains: &ObserverGains) -> Option<ErrorSpectrum> {
        let k = self.samples as f32;
        let omega_e = self.omega_e_sum / k.max(1.0);
        // (Non-finite sums never happen: `add` takes finite values only.)
        if self.periods() < 1.0 || omega_e == 0.0 {
            return None;
        }
        let mut eps_m = [0.0f32; SURVEY_HARMONICS];
        let mut harmonic_power = 0.0;
        for (a, s) in eps_m.iter_mut().zip(&self.sums) {
            *a = 2.0 * s.abs() / k;
            harmonic_power += 0.5 * *a * *a;
        }
        // What is not in the harmonics is noise (and harmonics above 16); its DFT bin
        // amplitude is 2σ/√K.
        let noise_power = (self.eps2_sum / k - harmonic_power).max(0.0);
        let bin_noise = 2.0 * sqrt_f32(noise_power / k);
        let mut out = ErrorSpectrum {
            amplitude_rad: [0.0; SURVEY_HARMONICS],
            floor_rad: 4.0 * bin_noise,
            periods: self.periods(),
        };
        for (m, (a, e)) in out.amplitude_rad.iter_mut().zip(eps_m).enumerate() {
            *a = e * gains.inverse_error_transfer((m + 1) as f32 * omega_e).abs();
        }
        Some(out)
    }
}

/// The path that nulls error harmonic `m` (1..=16): offset, C/D, then h = m + 1, and
/// h = 1 - m where m + 1 would pass |h| ≤ 15.
pub fn path_for(m: u8) -> Option<PathKind> {
    match m {
        1 => Some(PathKind::Offset),
        2 => Some(PathKind::AmplitudeQuadrature),
        3..=14 => Some(PathKind::Harmonic(m as i8 + 1)),
        15..=16 => Some(PathKind::Harmonic(1 - m as i8)),
        _ => None,
    }
}

/// A bank chosen from a spectrum, and the harmonics above the floor left without a path.
#[derive(Clone, Debug, PartialEq)]
pub struct Allocation {
    /// In order of m.
    pub paths: heapless::Vec<PathKind, MAX_PATHS>,
    /// Harmonics m above the floor (and `min_rad`) with no path: the bank was full.
    pub unobserved: heapless::Vec<u8, SURVEY_HARMONICS>,
}

/// The `max_paths` (≤ [`MAX_PATHS`]) largest harmonics that clear their noise floor and
/// `min_rad` (rad, sensor electrical), each given its path.
pub fn allocate(spectrum: &ErrorSpectrum, max_paths: usize, min_rad: f32) -> Allocation {
    let mut a = Allocator::new(max_paths, min_rad);
    while !a.step(spectrum) {}
    a.out
}

/// [`allocate`] a phase at a time ([`Allocator::step`]): in the adaptation task each
/// phase is a run of its own, so that none spans a control period.
#[derive(Clone, Debug)]
struct Allocator {
    max_paths: usize,
    min_rad: f32,
    /// The harmonics that clear both floors (largest first once sorted).
    order: heapless::Vec<u8, SURVEY_HARMONICS>,
    chosen: heapless::Vec<u8, MAX_PATHS>,
    phase: AllocPhase,
    out: Allocation,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum AllocPhase {
    Candidates,
    Sort,
    Split,
    Paths,
    Done,
}

impl Allocator {
    fn new(max_paths: usize, min_rad: f32) -> Self {
        Self {
            max_paths,
            min_rad,
            order: heapless::Vec::new(),
            chosen: heapless::Vec::new(),
            phase: AllocPhase::Candidates,
            out: Allocation {
                paths: heapless::Vec::new(),
                unobserved: heapless::Vec::new(),
            },
        }
    }

    /// The next phase on `spectrum` (the same every call); true once the allocation is
    /// complete.
    #[inline(never)]
    fn step(&mut self, spectrum: &ErrorSpectrum) -> bool {
        // Masked, not checked: no panic path in the adaptation task, and m is 1..=16.
        const _: () = assert!(SURVEY_HARMONICS.is_power_of_two());
        let amp =
            |m: u8| spectrum.amplitude_rad[(m as usize).wrapping_sub(1) & (SURVEY_HARMONICS - 1)];
        match self.phase {
            AllocPhase::Candidates => {
                for m in 1..=SURVEY_HARMONICS as u8 {
                    if amp(m) > spectrum.floor_rad && amp(m) > self.min_rad {
                        // Sixteen at most, room for each.
                        let _ = self.order.push(m);
                    }
                }
                self.phase = AllocPhase::Sort;
            }
            AllocPhase::Sort => {
                // Largest first, sorted after the others are dropped (a stable sort keeps
                // their order as among all sixteen).
                insertion_sort_by(&mut self.order, |a, b| amp(a) > amp(b));
                self.phase = AllocPhase::Split;
            }
            AllocPhase::Split => {
                let room = self.max_paths.min(MAX_PATHS);
                for &m in &self.order {
                    if self.chosen.len() < room {
                        let _ = self.chosen.push(m);
                    } else {
                        let _ = self.out.unobserved.push(m);
                    }
                }
                // In order of m (not `sort_unstable`: its code is kilobytes in the
                // firmware).
                insertion_sort_by(&mut self.chosen, |a, b| a < b);
                insertion_sort_by(&mut self.out.unobserved, |a, b| a < b);
                self.phase = AllocPhase::Paths;
            }
            AllocPhase::Paths => {
                for k in self.chosen.iter().filter_map(|&m| path_for(m)) {
                    let _ = self.out.paths.push(k);
                }
                self.phase = AllocPhase::Done;
            }
            AllocPhase::Done => {}
        }
        self.phase == AllocPhase::Done
    }
}

/// A round gives paths only to harmonics at least this share of the largest one still
/// without a path. What the observer follows of a large harmonic m' phase-modulates θ̂s,
/// the survey's reference, and puts sidebands of up to ~m·|δ| (a tenth or more of a
/// large harmonic m, docs/theory.md §8) at m ± m'; once the large ones are nulled, the
/// next round's survey sees no sidebands of them.
pub const ROUND_SHARE: f32 = 0.25;

/// What the surveys chose: the first round's spectrum (the error the first stage left),
/// the share-of-the-largest floor, the bank (the first stage's paths, then the
/// allocated ones), the harmonics left without a path, and the rounds it took.
#[derive(Clone, Debug, PartialEq)]
pub struct SurveyOutcome {
    pub spectrum: ErrorSpectrum,
    pub min_rad: f32,
    pub bank: Bank,
    pub unobserved: heapless::Vec<u8, SURVEY_HARMONICS>,
    pub rounds: u8,
}

/// One round of a bank from the data: `spectrum` was measured with `bank` adapted and
/// frozen; `min_rad` is the first round's share-of-the-largest floor. The bank grows by
/// the harmonics above the noise floor, `min_rad` and [`ROUND_SHARE`] of the largest
/// without a path, as many as it has room for. Returns the new bank, whether it is
/// complete (nothing added, or full), and, when complete, the harmonics above the
/// floors left without a path.
pub fn next_round(
    spectrum: &ErrorSpectrum,
    bank: &[PathKind],
    min_rad: f32,
) -> (Bank, bool, heapless::Vec<u8, SURVEY_HARMONICS>) {
    let mut round = NextRound::new(*spectrum, Bank::new(bank), min_rad);
    while !round.step() {}
    (round.bank, round.complete, round.unobserved)
}

/// [`next_round`] a phase at a time ([`NextRound::step`]): in the adaptation task each
/// phase is a run of its own (all at once it spanned two 40 kHz control periods).
#[derive(Clone, Debug)]
pub struct NextRound {
    /// The spectrum with the bank's harmonics removed.
    rest: ErrorSpectrum,
    min_rad: f32,
    /// The bank so far, then the new one.
    bank: Bank,
    alloc: Option<Allocator>,
    complete: bool,
    unobserved: heapless::Vec<u8, SURVEY_HARMONICS>,
    phase: RoundPhase,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum RoundPhase {
    Rest,
    Allocate,
    Bank,
    Unobserved,
    Done,
}

impl NextRound {
    pub fn new(spectrum: ErrorSpectrum, bank: Bank, min_rad: f32) -> Self {
        Self {
            rest: spectrum,
            min_rad,
            bank,
            alloc: None,
            complete: false,
            unobserved: heapless::Vec::new(),
            phase: RoundPhase::Rest,
        }
    }

    /// The next phase; true once the round is chosen ([`Self::chosen`]).
    #[inline(never)]
    pub fn step(&mut self) -> bool {
        match self.phase {
            RoundPhase::Rest => {
                for p in self.bank.as_slice() {
                    if let Some(a) = self
                        .rest
                        .amplitude_rad
                        .get_mut((p.error_harmonic() as usize).wrapping_sub(1))
                    {
                        *a = 0.0;
                    }
                }
                let largest = self
                    .rest
                    .amplitude_rad
                    .iter()
                    .fold(0.0f32, |a, &b| a.max(b));
                let room = MAX_PATHS.saturating_sub(self.bank.as_slice().len());
                self.alloc = Some(Allocator::new(
                    room,
                    self.min_rad.max(ROUND_SHARE * largest),
                ));
                self.phase = RoundPhase::Allocate;
            }
            RoundPhase::Allocate => {
                let done = match &mut self.alloc {
                    Some(a) => a.step(&self.rest),
                    None => true,
                };
                if done {
                    self.phase = RoundPhase::Bank;
                }
            }
            RoundPhase::Bank => {
                let mut kinds: heapless::Vec<PathKind, MAX_PATHS> = heapless::Vec::new();
                let added = self.alloc.as_ref().map_or(&[][..], |a| &a.out.paths[..]);
                for k in self.bank.as_slice().iter().chain(added) {
                    let _ = kinds.push(*k);
                }
                self.complete = added.is_empty() || kinds.len() >= MAX_PATHS;
                self.bank = Bank::new(&kinds);
                self.phase = RoundPhase::Unobserved;
            }
            RoundPhase::Unobserved => {
                if self.complete {
                    // The kinds in the bank as a set of their codes (a search per
                    // harmonic took a control period's worth of the task's time).
                    let in_bank = self
                        .bank
                        .as_slice()
                        .iter()
                        .fold(0u32, |set, &k| set | 1 << (PackedBank::code(k) & 31));
                    for (i, &a) in self.rest.amplitude_rad.iter().enumerate() {
                        let m = i as u8 + 1;
                        let pathed = path_for(m)
                            .is_some_and(|k| in_bank & 1 << (PackedBank::code(k) & 31) != 0);
                        if a > self.rest.floor_rad && a > self.min_rad && !pathed {
                            let _ = self.unobserved.push(m);
                        }
                    }
                }
                self.phase = RoundPhase::Done;
            }
            RoundPhase::Done => {}
        }
        self.phase == RoundPhase::Done
    }

    /// The new bank, whether it is complete, and the harmonics left without a path (as
    /// [`next_round`] returns them), once [`Self::step`] returned true.
    pub fn chosen(&self) -> (&Bank, bool, &heapless::Vec<u8, SURVEY_HARMONICS>) {
        (&self.bank, self.complete, &self.unobserved)
    }
}

/// The share-of-the-largest floor of a first round's spectrum ([`MIN_SHARE`]).
pub fn min_rad_of(spectrum: &ErrorSpectrum) -> f32 {
    MIN_SHARE * spectrum.amplitude_rad.iter().fold(0.0f32, |a, &b| a.max(b))
}

/// Sort `v` (at most [`SURVEY_HARMONICS`] entries are sorted) so that
/// `before(v[i], v[j])` holds for i < j where it decides, keeping the order of the
/// others (insertion sort): a few entries, no allocation, no panic path (masked
/// indices into a copy).
fn insertion_sort_by(v: &mut [u8], before: impl Fn(u8, u8) -> bool) {
    const MASK: usize = SURVEY_HARMONICS - 1;
    let n = v.len().min(SURVEY_HARMONICS);
    let mut a = [0u8; SURVEY_HARMONICS];
    for (d, s) in a.iter_mut().zip(v.iter()) {
        *d = *s;
    }
    for end in 1..n {
        let x = a[end & MASK];
        let mut j = end;
        while j > 0 && before(x, a[(j - 1) & MASK]) {
            a[j & MASK] = a[(j - 1) & MASK];
            j -= 1;
        }
        a[j & MASK] = x;
    }
    for (d, s) in v.iter_mut().zip(a.iter()) {
        *d = *s;
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::vec::Vec;

    /// The insertion sort is the standard library's stable sort, on every length up to
    /// the harmonics' and on orders with ties.
    #[test]
    fn the_sort_is_a_stable_sort() {
        let mut seed = 12345u32;
        for len in 0..=SURVEY_HARMONICS {
            for _ in 0..200 {
                let v: Vec<u8> = (0..len)
                    .map(|_| {
                        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                        (seed >> 24) as u8 % 7
                    })
                    .collect();
                let mut got = v.clone();
                insertion_sort_by(&mut got, |a, b| a > b);
                let mut want = v.clone();
                want.sort_by(|a, b| b.cmp(a));
                assert_eq!(got, want, "{v:?}");
            }
        }
    }
}
