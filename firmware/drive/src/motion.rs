//! Motion loops: the torque command from a position or speed reference and the estimate.
//!
//! Both place their poles on the estimated inertia Ĵ: position as `(s + ω)³` (PID on
//! the angle error), velocity as `(s + ω)²` (PI on the speed error), each with the
//! reference's acceleration as feed-forward. The integrator stops while the torque is
//! at its limit and the error would push it further (conditional integration).

use core::f32::consts::TAU;

/// A continuous angle as whole turns plus a remainder in [0, 2π): f32 keeps its
/// precision over any number of turns.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Angle {
    pub turns: i32,
    pub rad: f32,
}

impl Angle {
    /// `self - other` in radians (small differences stay exact).
    #[inline]
    pub fn minus(self, other: Angle) -> f32 {
        (self.turns.wrapping_sub(other.turns)) as f32 * TAU + (self.rad - other.rad)
    }

    /// `self + other`.
    #[inline]
    pub fn plus(self, other: Angle) -> Angle {
        let mut turns = self.turns.wrapping_add(other.turns);
        let mut rad = self.rad + other.rad;
        if rad >= TAU {
            rad -= TAU;
            turns = turns.wrapping_add(1);
        }
        Angle { turns, rad }
    }

    /// The same angle seen turning the other way.
    #[inline]
    pub fn negated(self) -> Angle {
        if self.rad > 0.0 {
            Angle {
                turns: self.turns.wrapping_neg().wrapping_sub(1),
                rad: TAU - self.rad,
            }
        } else {
            Angle {
                turns: self.turns.wrapping_neg(),
                rad: 0.0,
            }
        }
    }
}

/// What the application asks for (motor frame, mechanical).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MotionRef {
    /// Position (used in [`LoopMode::Position`]); the loop homes it to the measured
    /// angle when it starts, as a drive does at enable.
    pub theta: Angle,
    pub omega_rad_s: f32,
    /// Feed-forward acceleration.
    pub accel_rad_s2: f32,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoopMode {
    Position,
    Velocity,
}

/// A position or velocity loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionLoop {
    mode: LoopMode,
    inertia_kg_m2: f32,
    kp: f32,
    ki: f32,
    kd: f32,
    integral: f32,
    /// θ̂ - θ* when the loop started (position mode).
    home: Option<Angle>,
}

impl MotionLoop {
    pub fn new(mode: LoopMode, bandwidth_hz: f32, inertia_kg_m2: f32) -> Self {
        let w = TAU * bandwidth_hz;
        let (kd, kp, ki) = match mode {
            // (s + w)³: α = 3w·ė + 3w²·e + w³∫e
            LoopMode::Position => (3.0 * w, 3.0 * w * w, w * w * w),
            // (s + w)²: α = 2w·ė + w²∫ė
            LoopMode::Velocity => (2.0 * w, w * w, 0.0),
        };
        Self {
            mode,
            inertia_kg_m2,
            kp,
            ki,
            kd,
            integral: 0.0,
            home: None,
        }
    }

    /// θ̂ - θ* when the position loop started (None before, or in velocity mode).
    pub fn home(&self) -> Option<Angle> {
        self.home
    }

    /// Place the poles on another Ĵ, keeping the torque the integrator holds (its state
    /// is an acceleration): a bumpless change at speed.
    /// `per_inertia` is 1/`inertia_kg_m2`, which the caller works out once for all it
    /// changes.
    pub fn set_inertia(&mut self, inertia_kg_m2: f32, per_inertia: f32) {
        self.integral *= self.inertia_kg_m2 * per_inertia;
        self.inertia_kg_m2 = inertia_kg_m2;
    }

    /// Scale the torque the integrator holds by `k`: where the torque constant changes
    /// by `k`, the current it asks for (what balanced the load) stays.
    pub fn scale_torque(&mut self, k: f32) {
        self.integral *= k;
    }

    /// Hand the torque the integrator holds to `next`, which goes on from it (no dip
    /// where one loop takes over from the other at speed), and forget it.
    pub fn hand_over(&mut self, next: &mut MotionLoop) {
        if self.integral != 0.0 {
            next.integral = self.gain_i() * self.integral * self.inertia_kg_m2
                / (next.gain_i() * next.inertia_kg_m2);
        }
        self.reset();
    }

    /// The integrator's gain: its state times this is an acceleration.
    fn gain_i(&self) -> f32 {
        match self.mode {
            LoopMode::Position => self.ki,
            LoopMode::Velocity => self.kp,
        }
    }

    /// Forget the integrator and the homing (the loop is not in use).
    pub fn reset(&mut self) {
        self.integral = 0.0;
        self.home = None;
    }

    /// Torque command (N·m), limited to ±`limit_nm`.
    pub fn torque(
        &mut self,
        r: &MotionRef,
        theta: Angle,
        omega_rad_s: f32,
        t_s: f32,
        limit_nm: f32,
    ) -> f32 {
        let e_w = r.omega_rad_s - omega_rad_s;
        let (e_int, alpha_pd) = match self.mode {
            LoopMode::Position => {
                let home = *self.home.get_or_insert(Angle {
                    turns: theta.turns.wrapping_sub(r.theta.turns),
                    rad: theta.rad - r.theta.rad,
                });
                let e_th = r.theta.plus(home).minus(theta);
                (e_th, self.kd * e_w + self.kp * e_th)
            }
            LoopMode::Velocity => (e_w, self.kd * e_w),
        };
        let gain_i = self.gain_i();
        let integral = self.integral + e_int * t_s;
        let unclamped = self.inertia_kg_m2 * (r.accel_rad_s2 + alpha_pd + gain_i * integral);
        // min/max, not `clamp`: no panic path for a limit the compiler cannot prove.
        let torque = mras::min_f32(mras::max_f32(unclamped, -limit_nm), limit_nm);
        // Integrate unless that winds further into the limit.
        if torque == unclamped || (unclamped > limit_nm) != (e_int > 0.0) {
            self.integral = integral;
        }
        torque
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angles_subtract_across_turns_and_negate() {
        let a = Angle {
            turns: 1000,
            rad: 0.1,
        };
        let b = Angle {
            turns: 999,
            rad: 6.2,
        };
        assert!((a.minus(b) - (TAU + 0.1 - 6.2)).abs() < 1e-5);
        let n = a.negated();
        assert_eq!(n.turns, -1001);
        assert!((n.rad - (TAU - 0.1)).abs() < 1e-6);
        let zero = Angle { turns: 3, rad: 0.0 }.negated();
        assert_eq!((zero.turns, zero.rad), (-3, 0.0));
        let s = b.plus(Angle { turns: 0, rad: 0.2 });
        assert_eq!(s.turns, 1000);
        assert!(s.rad < 0.2);
    }

    /// A rigid rotor on the loop: the velocity loop settles at the reference, and the
    /// integrator does not wind up while the torque is limited.
    #[test]
    fn velocity_loop_settles_without_windup() {
        let j = 2e-4;
        let mut l = MotionLoop::new(LoopMode::Velocity, 10.0, j);
        let (mut w, dt) = (0.0f32, 50e-6);
        let r = MotionRef {
            omega_rad_s: 100.0,
            ..MotionRef::default()
        };
        let mut peak = 0.0f32;
        for _ in 0..40_000 {
            let t = l.torque(&r, Angle::default(), w, dt, 0.05);
            w += (t - 0.01) / j * dt;
            peak = peak.max(w);
        }
        assert!((w - 100.0).abs() < 0.1, "{w}");
        // Limited acceleration for ~0.5 s; a wound-up integrator overshoots by far more.
        assert!(peak < 110.0, "overshoot to {peak}");
    }

    /// A loaded rotor at speed on the velocity loop; the position loop takes over with
    /// the torque the integrator held: no step in the torque, no dip in the speed.
    /// (From an empty integrator the load would brake it by far more.)
    #[test]
    fn a_loop_takes_over_the_torque_at_speed() {
        let (j, load_nm, dt) = (2e-5, 0.05, 50e-6);
        let mut speed = MotionLoop::new(LoopMode::Velocity, 10.0, j);
        let mut position = MotionLoop::new(LoopMode::Position, 10.0, j);
        let r = |t: f32| MotionRef {
            theta: Angle {
                turns: 0,
                rad: 100.0 * t,
            },
            omega_rad_s: 100.0,
            accel_rad_s2: 0.0,
        };
        let (mut w, mut th, mut held) = (100.0f32, 0.0f32, 0.0);
        for k in 0..40_000 {
            held = speed.torque(&r(k as f32 * dt), Angle::default(), w, dt, 1.0);
            w += (held - load_nm) / j * dt;
        }
        assert!((held - load_nm).abs() < 1e-4, "{held}");
        speed.hand_over(&mut position);
        let (mut slowest, mut first) = (w, None);
        for k in 0..20_000 {
            let t = position.torque(&r(k as f32 * dt), Angle { turns: 0, rad: th }, w, dt, 1.0);
            first.get_or_insert(t);
            w += (t - load_nm) / j * dt;
            th += w * dt;
            slowest = slowest.min(w);
        }
        let first = first.unwrap();
        assert!(
            (first - held).abs() < 1e-3 * load_nm,
            "{first} after {held}"
        );
        assert!(slowest > 99.9, "dipped to {slowest}");
        // The speed loop forgot it; a hand-over from an empty loop keeps the other's.
        let mut again = position;
        speed.hand_over(&mut again);
        assert_eq!(again, position);
    }

    #[test]
    fn position_loop_homes_and_tracks() {
        let j = 2e-4;
        let mut l = MotionLoop::new(LoopMode::Position, 20.0, j);
        let (mut th, mut w, dt) = (5.0f32, 0.0f32, 50e-6);
        for k in 0..40_000 {
            let t = k as f32 * dt;
            let r = MotionRef {
                theta: Angle {
                    turns: 0,
                    rad: 0.5 * t,
                },
                omega_rad_s: 0.5,
                accel_rad_s2: 0.0,
            };
            let tq = l.torque(&r, Angle { turns: 0, rad: th }, w, dt, 1.0);
            w += tq / j * dt;
            th += w * dt;
        }
        // Homed at 5 rad: after 2 s at 0.5 rad/s it is at 6 rad.
        assert!((th - 6.0).abs() < 1e-3, "{th}");
    }
}
