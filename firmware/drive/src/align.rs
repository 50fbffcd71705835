//! The electrical alignment: where the rotor's electrical zero lies in the sensor's
//! angle, and which way the sensor turns against the phase sequence.
//!
//! The FOC angle is `θe = dir·(p/N)·θ̂s + offset_e` (p pole pairs, N sensor periods per
//! revolution, θ̂s the sensor-electrical estimate). With `N | p` a sensor period holds a
//! whole number of electrical periods, so the turn the sensor cannot tell apart (2π/N
//! mechanical) is a whole number of electrical turns and drops out.
//!
//! After the rotor has been pulled to θe = 0 (Align), the field is turned open loop with
//! d-axis current over exactly one sensor period, `2π·p/N` electrical, held, and turned
//! back, each way with a raised-cosine angle profile. Measured:
//! - the sensor's travel against the commanded angle, a least-squares slope over both
//!   directions: `±1/(p/N)` when p and N are right (its sign is the direction); the
//!   rotor's lag cancels between the directions, and a rotor ringing on the field's
//!   stiffness averages out. Otherwise it gives the motor's pole pairs, `p_in_force /
//!   (slope·p_in_force/N)`; the commissioning puts that count in force and sweeps again,
//!   since the offset averages the sensor's harmonic errors out only over one whole
//!   sensor period of the count in force;
//! - the offset, as the mean of `θ_cmd - dir·(p/N)·θ̂s` weighted by the commanded angle
//!   step: a uniform average over one sensor period, so the sensor's harmonic errors
//!   average out, and over both directions, so the rotor's and the observer's lag behind
//!   the field cancel.
//!
//! The sweep runs on the raw sensor, so its offset holds the raw angle's mean error over
//! a period. The decoupling paths move the corrected angle's mean (the C/D path, for one,
//! corrects quadrature on X alone), so after adaptation [`ShiftMeter`] measures the mean
//! of `arg Zd - arg Z` at speed and the offset is moved by it onto the corrected angle.

use crate::telemetry::SweepResult;
use calib_record::Alignment;
use core::f32::consts::{PI, TAU};

/// The hold at each end, as a fraction of one direction's duration: the rotor settles
/// before the field turns back (the fit leaves the holds out: the command stands).
const HOLD_FRACTION: f32 = 0.25;

/// Whether a sensor of `sensor_periods` periods per revolution names the electrical
/// angle of `pole_pairs` pole pairs: N divides p (p ≥ 1), so its 2π/N ambiguity is a
/// whole number of electrical turns.
pub fn pole_pairs_serve(pole_pairs: u16, sensor_periods: u16) -> bool {
    pole_pairs > 0 && pole_pairs.checked_rem(sensor_periods) == Some(0)
}

/// Wrap an angle into [-π, π] (nearest whole turn removed; exact for |x| < 1e4 rad).
#[inline]
pub fn wrap_pi(x: f32) -> f32 {
    // Rounded without a branch (ties to even: both ends are the same angle).
    x - mras::round_f32_fast(x * (1.0 / TAU)) * TAU
}

/// `libm::roundf` (half away from zero), bit for bit, through an integer where `x` has a
/// fraction: the generic `roundf` cost the sweep's last control period about 35 cycles
/// a call.
#[inline]
pub fn round_f32(x: f32) -> f32 {
    // NaN, infinities and |x| >= 2^23 (integers already) as they are.
    if x.is_nan() || libm::fabsf(x) >= 8_388_608.0 {
        return x;
    }
    let t = x as i32 as f32;
    // Exact: x and its truncation share their sign and exponent range.
    let r = if libm::fabsf(x - t) >= 0.5 {
        t + libm::copysignf(1.0, x)
    } else {
        t
    };
    // -0.4 rounds to -0.0, as `roundf`.
    libm::copysignf(r, x)
}

/// The electrical angle of the rotor from the sensor-electrical estimate.
#[inline]
pub fn electrical_angle(a: &Alignment, electrical_per_sensor: f32, theta_s_rad: f32) -> f32 {
    let k = if a.reversed {
        -electrical_per_sensor
    } else {
        electrical_per_sensor
    };
    wrap_pi(k * theta_s_rad + a.offset_e_rad)
}

/// One sweep in progress.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sweep {
    t_s: f32,
    last_cmd_rad: f32,
    /// θ̂s (absolute, [0, 2π)) and θ̂ unwrapped (mechanical) at the start, and the
    /// command's phase rate π/duration (rad/s; a division once, not every period).
    start: Option<(f32, f32, f32)>,
    /// Sums weighted by the commanded angle's step (a uniform average over the
    /// commanded angle, the holds left out): the command about the sweep's middle `c`,
    /// the sensor's travel `s`, and their products.
    sum_w: f32,
    sum_w_c: f32,
    sum_w_s: f32,
    sum_w_cc: f32,
    sum_w_cs: f32,
    /// Set when both directions are done: the sums, which stop there, and what the fit
    /// needs besides. The fit itself is worked out by whoever reads it
    /// ([`SweepFit::result`]): in the control period that ended the sweep it was that
    /// period's longest part, and the supervisor reads its snapshot with the control
    /// interrupt masked.
    ended: Option<SweepFit>,
}

/// A finished sweep's sums and constants: [`SweepFit::result`] fits them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SweepFit {
    sum_w: f32,
    sum_w_c: f32,
    sum_w_s: f32,
    sum_w_cc: f32,
    sum_w_cs: f32,
    k: f32,
    sensor_periods: f32,
    s0_abs: f32,
}

impl Sweep {
    /// The finished sweep's fit, once both directions are done.
    pub fn fit(&self) -> Option<SweepFit> {
        self.ended
    }

    /// The result, once both directions are done.
    pub fn result(&self) -> Option<SweepResult> {
        self.ended.map(|f| f.result())
    }

    /// Commanded electrical angle at this period, and the measurement of the sensor's
    /// state at it: `theta_e_rad` (θ̂s in [0, 2π)) and `theta_unwrapped_rad` (mechanical,
    /// continuous, from the estimate of this period).
    ///
    /// `cos` is the caller's cosine (the control period's trigonometry), `k` is p/N.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        duration_s: f32,
        dt_s: f32,
        k: f32,
        sensor_periods: f32,
        theta_e_rad: f32,
        theta_unwrapped_rad: f32,
        cos: impl Fn(f32) -> f32,
    ) -> f32 {
        let span = TAU * k;
        let hold = HOLD_FRACTION * duration_s;
        let t = self.t_s;
        self.t_s += dt_s;
        let (s0_abs, s0_mech, rate_rad_s) =
            *self
                .start
                .get_or_insert((theta_e_rad, theta_unwrapped_rad, PI / duration_s));
        // Sensor-electrical travel since the start.
        let s_rel = sensor_periods * (theta_unwrapped_rad - s0_mech);
        let back_start = duration_s + hold;
        let cmd = if t < duration_s {
            0.5 * span * (1.0 - cos(rate_rad_s * t))
        } else if t < back_start {
            span
        } else if t < back_start + duration_s {
            0.5 * span * (1.0 + cos(rate_rad_s * (t - back_start)))
        } else {
            0.0
        };
        if self.ended.is_some() {
            return cmd;
        }
        let w = libm::fabsf(cmd - self.last_cmd_rad);
        self.last_cmd_rad = cmd;
        let c = cmd - 0.5 * span;
        self.sum_w += w;
        self.sum_w_c += w * c;
        self.sum_w_s += w * s_rel;
        self.sum_w_cc += w * c * c;
        self.sum_w_cs += w * c * s_rel;
        if t >= back_start + duration_s + hold {
            self.ended = Some(SweepFit {
                sum_w: self.sum_w,
                sum_w_c: self.sum_w_c,
                sum_w_s: self.sum_w_s,
                sum_w_cc: self.sum_w_cc,
                sum_w_cs: self.sum_w_cs,
                k,
                sensor_periods,
                s0_abs,
            });
        }
        cmd
    }
}

impl SweepFit {
    /// The sweep's result: ratio, pole pairs, alignment.
    pub fn result(&self) -> SweepResult {
        let (k, sensor_periods, s0_abs) = (self.k, self.sensor_periods, self.s0_abs);
        // The sensor's travel against the command, least squares over both directions:
        // the rotor's lag behind the field is opposite in each and cancels, and a
        // rotor ringing on the field's stiffness averages out (one reading at the
        // hold's end would take its swing for travel).
        // One division: the sweep ends inside a control period.
        let inv_n = 1.0 / mras::max_f32(self.sum_w, f32::MIN_POSITIVE);
        let (mean_c, mean_s) = (self.sum_w_c * inv_n, self.sum_w_s * inv_n);
        let var = self.sum_w_cc * inv_n - mean_c * mean_c;
        let cov = self.sum_w_cs * inv_n - mean_c * mean_s;
        // Sensor radians per electrical radian: ±1/k when p and N are right.
        let slope = if var > 0.0 { cov / var } else { 0.0 };
        let reversed = slope < 0.0;
        let ratio = libm::fabsf(slope) * k;
        // The field turned 2π·k electrical, which moves a rotor of p pole pairs by
        // 2π·k/p mechanical: the sensor by k·N/p periods. A rotor that did not move
        // gives a count beyond any motor's (finite: no infinity on the stream).
        let in_force = k * sensor_periods;
        let pole_pairs = in_force / mras::max_f32(ratio, 1e-6);
        // The nearest count whose electrical turns a sensor period holds whole (N | p).
        let whole = mras::min_f32(
            mras::max_f32(round_f32(pole_pairs / sensor_periods), 1.0) * sensor_periods,
            u16::MAX as f32,
        );
        let offset_e_rad = if self.sum_w > 0.0 && ratio > 0.0 {
            let mean_cmd = mean_c + 0.5 * TAU * k;
            let dir = if reversed { -1.0 } else { 1.0 };
            wrap_pi(mean_cmd - dir * k * (s0_abs + mean_s))
        } else {
            0.0
        };
        SweepResult {
            ratio,
            pole_pairs,
            whole_pole_pairs: whole as u16,
            sensor_periods: round_f32(sensor_periods) as u16,
            alignment: Alignment {
                offset_e_rad,
                reversed,
                pole_pairs: round_f32(in_force) as u16,
            },
        }
    }
}

/// Mean of `sin(arg Zd - arg Z)`: the shift of the corrected angle against the raw one
/// (sensor electrical), for uniformly covered angles.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ShiftMeter {
    sum: f32,
    count: u32,
}

/// Samples before the mean is reported: several sensor periods at the commissioning
/// speed.
const SHIFT_SAMPLES: u32 = 2000;

impl ShiftMeter {
    /// Add one sample's raw vector `z` and decoupled vector `zd`.
    #[inline]
    pub fn add(&mut self, z: (f32, f32), zd: (f32, f32)) {
        let cross = zd.1 * z.0 - zd.0 * z.1;
        let n2 = (zd.0 * zd.0 + zd.1 * zd.1) * (z.0 * z.0 + z.1 * z.1);
        if n2 > f32::MIN_POSITIVE {
            // One Newton step: the weight to 2e-3 at worst, nearly the same on every
            // sample (|z| and |zd| hold steady), so the shift moves by at most 2e-3 of
            // itself (µrad); a second step cost the 40 kHz period's worst case its margin.
            self.sum += cross * mras::inv_sqrt_steps_f32::<1>(n2);
            self.count += 1;
        }
    }

    /// The mean shift (rad), once enough samples came in.
    pub fn shift_rad(&self) -> Option<f32> {
        (self.count >= SHIFT_SAMPLES).then(|| self.sum / self.count as f32)
    }
}

/// A [`ShiftMeter`]'s sums with the alignment they move: the corrected offset, worked
/// out by whoever reads it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShiftReading {
    /// The offset in force (electrical).
    pub offset_e_rad: f32,
    /// Electrical radians per sensor electrical radian, with the alignment's direction.
    pub electrical_per_sensor: f32,
    pub meter: ShiftMeter,
}

impl ShiftReading {
    /// `θe = dir·k·(θs_raw) + offset = dir·k·(θs_corrected - shift) + offset`: the offset
    /// for the corrected angle, once the shift is measured over enough samples.
    pub fn corrected_offset_e_rad(&self) -> Option<f32> {
        let shift = self.meter.shift_rad()?;
        Some(wrap_pi(
            self.offset_e_rad - self.electrical_per_sensor * shift,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_is_roundf_bit_for_bit() {
        let same = |x: f32| {
            assert_eq!(round_f32(x).to_bits(), libm::roundf(x).to_bits(), "{x}");
        };
        for x in [
            0.0f32,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.499_999_97,
            -0.499_999_97,
            1e-30,
            8_388_607.5,
            -8_388_607.5,
            8_388_608.0,
            1e9,
            f32::MAX,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ] {
            same(x);
        }
        let mut x = 1e-3f32;
        while x < 1e8 {
            for x in [x, -x, x + 0.5, -x - 0.5, x.next_up(), (-x).next_down()] {
                same(x);
            }
            x *= 1.013;
        }
    }

    #[test]
    fn wrap_pi_keeps_angles_in_range() {
        for k in -200..200 {
            let x = k as f32 * 0.37;
            let w = wrap_pi(x);
            assert!((-PI..=PI).contains(&w), "{x} -> {w}");
            let turns = (x - w) / TAU;
            assert!((turns - libm::roundf(turns)).abs() < 1e-4, "{x} -> {w}");
        }
    }

    /// An ideal rotor that follows the field: the sensor reads `dir·θe/k + s0` (sensor
    /// electrical) plus a periodic error; the sweep finds dir, ratio 1 and the offset.
    fn sweep_ideal(k: f32, n: f32, reversed: bool, s0: f32, err: f32) -> SweepResult {
        sweep_motor(k, k, n, reversed, s0, err)
    }

    /// [`sweep_ideal`] with the sweep told `k_in_force` = p/N of a rotor whose p/N is
    /// `k_true`.
    fn sweep_motor(
        k_in_force: f32,
        k_true: f32,
        n: f32,
        reversed: bool,
        s0: f32,
        err: f32,
    ) -> SweepResult {
        let mut s = Sweep::default();
        let dt = 50e-6;
        let dir = if reversed { -1.0 } else { 1.0 };
        let mut cmd = 0.0f32;
        for _ in 0..40_000 {
            let true_s = s0 + dir * cmd / k_true;
            let meas = true_s + err * libm::sinf(3.0 * true_s + 0.4);
            let theta_e = meas - TAU * libm::floorf(meas / TAU);
            // Mechanical unwrapped = sensor electrical / N (relative values only matter).
            cmd = s.step(0.2, dt, k_in_force, n, theta_e, meas / n, libm::cosf);
            if let Some(r) = s.result() {
                return r;
            }
        }
        panic!("sweep did not finish");
    }

    #[test]
    fn finds_direction_ratio_and_offset_despite_a_harmonic_error() {
        for (k, n) in [(2.0, 2.0), (4.0, 1.0), (1.0, 4.0)] {
            for reversed in [false, true] {
                for s0 in [0.3, 2.0, 5.9] {
                    let r = sweep_ideal(k, n, reversed, s0, 0.05);
                    assert_eq!(r.alignment.reversed, reversed);
                    // The harmonic error leans the fitted slope a little (a 3rd
                    // harmonic of 0.05 rad: 0.5 % at most here).
                    assert!((r.ratio - 1.0).abs() < 6e-3, "{r:?}");
                    // At the start the rotor is at θe = 0 and the sensor at s0.
                    let a = r.alignment;
                    let e = electrical_angle(&a, k, s0 - TAU * libm::floorf(s0 / TAU));
                    assert!(e.abs() < 2e-3, "k {k} rev {reversed} s0 {s0}: {e}");
                }
            }
        }
    }

    /// A motor of another pole-pair count than the one in force: the travel gives its
    /// count and the nearest one N divides; the alignment stays the count in force's.
    #[test]
    fn finds_the_pole_pairs_of_another_motor() {
        for (p_in_force, n) in [(4.0f32, 2.0f32), (4.0, 1.0), (8.0, 2.0)] {
            for p_true in [2.0f32, 4.0, 6.0, 8.0, 12.0] {
                for reversed in [false, true] {
                    let r = sweep_motor(p_in_force / n, p_true / n, n, reversed, 2.0, 0.0);
                    assert_eq!(r.alignment.reversed, reversed);
                    assert!((r.pole_pairs - p_true).abs() < 1e-3 * p_true, "{r:?}");
                    assert_eq!(r.whole_pole_pairs, p_true as u16);
                    assert_eq!(r.alignment.pole_pairs, p_in_force as u16);
                    assert!((r.ratio - p_in_force / p_true).abs() < 1e-3, "{r:?}");
                }
            }
        }
        // N = 2 on a 3-pole-pair motor: the nearest even count, 1 pole pair away.
        let r = sweep_motor(2.0, 1.5, 2.0, false, 0.5, 0.0);
        assert!((r.pole_pairs - 3.0).abs() < 1e-3, "{r:?}");
        assert!([2, 4].contains(&r.whole_pole_pairs), "{r:?}");
        // A rotor that does not move: a finite, huge count.
        let mut s = Sweep::default();
        let mut n = 0;
        while s.result().is_none() && n < 40_000 {
            s.step(0.2, 50e-6, 2.0, 2.0, 1.0, 0.5, libm::cosf);
            n += 1;
        }
        let r = s.result().unwrap();
        assert!(r.pole_pairs.is_finite() && r.pole_pairs > 1e5, "{r:?}");
    }
}
