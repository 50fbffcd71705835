//! Deliberately broken drives for `cargo xtask mutants`, never for a board. Each is a
//! bug the core's own health checks cannot see (the observer and the MRAS stay healthy),
//! so only a measure taken at the plant can catch it: the emulator's power-up test must
//! fail on each. Without the features every item here is the identity.

use mras::Estimate;

/// The electrical angle the drive commutes with in the motion setpoints. With
/// `mutant-electrical-offset` it is 0.3 rad (electrical) off the angle it aligned, as a
/// wrong sign or unit in the offset's use would make it; torque per amp falls to
/// cos 0.3 = 0.955 and the speed loop hides it. (`θ + 0.0` is not the identity in
/// IEEE arithmetic, so the default build must not add a zero.)
#[inline(always)]
pub fn commutation_angle(theta_e_rad: f32) -> f32 {
    if cfg!(feature = "mutant-electrical-offset") {
        theta_e_rad + 0.3
    } else {
        theta_e_rad
    }
}

/// The estimate the drive commutes with and streams. With `mutant-correction-sign` the
/// correction the core applies to the raw angle is taken with the wrong sign: the raw
/// angle minus what the decoupling vector moved it by, so the angle carries twice the
/// sensor's error while the core itself converges as usual.
#[inline(always)]
pub fn estimate_in_use(est: Estimate, raw_xy: (f32, f32), sensor_periods: f32) -> Estimate {
    if cfg!(feature = "mutant-correction-sign") {
        flip_correction(est, raw_xy, sensor_periods)
    } else {
        let _ = (raw_xy, sensor_periods);
        est
    }
}

fn flip_correction(mut est: Estimate, (x, y): (f32, f32), sensor_periods: f32) -> Estimate {
    use core::f32::consts::TAU;
    let raw_e = libm::atan2f(y, x);
    let correction = crate::align::wrap_pi(est.theta_e_rad - raw_e);
    let wrap = |a: f32| {
        let w = libm::fmodf(a, TAU);
        if w < 0.0 {
            w + TAU
        } else {
            w
        }
    };
    est.theta_e_rad = wrap(est.theta_e_rad - 2.0 * correction);
    est.theta_rad = wrap(est.theta_rad - 2.0 * correction / sensor_periods);
    est
}

/// Whether the control period reads phases a and b whatever the duties (the scheme of a
/// board that samples two fixed shunts at the counter peak). With
/// `mutant-fixed-current-phases` it does: above about 0.9 duty on a or b its shunt no
/// longer conducts when it is read.
#[inline(always)]
pub fn current_phases_fixed() -> bool {
    cfg!(feature = "mutant-fixed-current-phases")
}
