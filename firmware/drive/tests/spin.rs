//! The motion's identification on simulated rotors: the least squares find J/kt, B/kt
//! and the starting speed through a sensor's periodic error and a speed loop's ripple;
//! the coast's two halves give ψ whatever the frame's error and what is odd in id.

use core::f32::consts::TAU;
use drive::spin::{
    FluxMeter, InertiaFit, Probe, Travel, PROBE_TIMEOUT_S, PROBE_TRAVEL_RAD, START_SPEED_TOLERANCE,
};

const DT: f32 = 1e-3;

#[test]
fn travel_unwraps_in_both_directions() {
    let mut t = Travel::new(6.2);
    assert!((t.add(0.1) - (TAU - 6.2 + 0.1)).abs() < 1e-5);
    assert!((t.add(6.0) - (TAU - 6.2 + 0.1 - (0.1 + TAU - 6.0))).abs() < 1e-5);
}

/// A rigid rotor under a current `iq(t, ω)` against viscous friction, sampled at the
/// supervisor's rate: (θ wrapped, with the sensor's error `err(θ)`, and ∫iq dt) per
/// step, integrated finely between samples.
fn spin(
    seconds: f32,
    omega0: f32,
    j_over_kt: f32,
    b_over_kt: f32,
    iq: impl Fn(f32, f32) -> f32,
    err: &dyn Fn(f32) -> f32,
) -> Vec<(f32, f32)> {
    let (mut th, mut w, mut q) = (0.3f64, omega0 as f64, 0.0f64);
    let sub = 50;
    let h = (DT / sub as f32) as f64;
    let mut out = Vec::new();
    for k in 0..(seconds / DT) as usize {
        let sensed = (th as f32 + err(th as f32)).rem_euclid(TAU);
        out.push((sensed, q as f32));
        for _ in 0..sub {
            let i = iq(k as f32 * DT, w as f32) as f64;
            let a = (i - b_over_kt as f64 * w) / j_over_kt as f64;
            q += i * h;
            th += w * h + 0.5 * a * h * h;
            w += a * h;
        }
    }
    out
}

fn fit(samples: &[(f32, f32)], omega_ref_rad_s: f32) -> Option<drive::spin::MotionFit> {
    let mut f = InertiaFit::about(omega_ref_rad_s);
    for &(th, q) in samples {
        f.add(DT, th, q);
    }
    f.solve()
}

/// A speed loop's spin-up on a 180 mrad pk-pk sensor (its error at 2 and 4 per
/// revolution, as the commissioning scenario's), the current following a ramp with a
/// ripple at the sensor's frequencies: J/kt within 12 % (the spin-up's rough fit: at low
/// speed the raw sensor's error is slow enough to pass the fit's filters, and it biases
/// the lightest rotor's by 11 %); and Motion's dip of 30 % and back on a corrected
/// sensor, the regressors about the speed it starts at: J/kt within 0.5 %. Friction as
/// the current it takes at the speed, within 1 % (one speed region separates viscous
/// from constant friction only weakly); for the lightest and the heaviest rotor per amp
/// of the ratings.
/// A run: its name, the speed reference, the starting speed, the sensor's error and the
/// tolerances on J/kt and on the friction.
type Run<'a> = (
    &'a str,
    &'a dyn Fn(f32) -> f32,
    f32,
    &'a dyn Fn(f32) -> f32,
    f32,
    f32,
);

#[test]
fn the_fit_finds_inertia_and_friction_through_the_sensors_error() {
    let raw = |th: f32| 0.06 * libm::sinf(2.0 * th + 0.4) + 0.03 * libm::sinf(4.0 * th - 1.0);
    let target = 125.7;
    for (j_over_kt, b_over_kt) in [(1e-4, 1.3e-2), (1.25e-2, 1.3e-2), (2e-3, 1e-3)] {
        // A P loop on the reference, with the sensor's ripple in its speed.
        let spin_up = |t: f32| target * (t / 0.2).min(1.0);
        let dip = |t: f32| {
            let u = t / 0.1;
            let d = if u < 1.0 {
                u
            } else if u < 2.0 {
                2.0 - u
            } else {
                0.0
            };
            target * (1.0 - 0.3 * d)
        };
        let runs: [Run; 2] = [
            ("spin-up, raw sensor", &spin_up, 0.0, &raw, 0.12, 0.01),
            ("dip, corrected sensor", &dip, target, &|_| 0.0, 0.005, 0.01),
        ];
        for (what, reference, w0, err, tol_j, tol_b) in runs {
            let iq = |t: f32, w: f32| {
                let ripple = 0.2 * w * libm::sinf(2.0 * w * t);
                (j_over_kt * 60.0 * (reference(t) - w + ripple) + b_over_kt * w).clamp(-10.0, 10.0)
            };
            let s = spin(0.5, w0, j_over_kt, b_over_kt, iq, err);
            let f = fit(&s, w0).unwrap_or_else(|| panic!("J/kt {j_over_kt}, {what}: no fit"));
            let rel = |a: f32, b: f32| (a / b - 1.0).abs();
            assert!(
                rel(f.amps_per_accel_a_s2, j_over_kt) < tol_j,
                "{what}: {f:?}"
            );
            let friction = f.amps_per_speed_a_s * target + f.amps_constant_a;
            assert!(rel(friction, b_over_kt * target) < tol_b, "{what}: {f:?}");
            assert!(f.starts_at(w0, target), "{what}: {f:?}");
        }
    }
}

/// A fit from a moving rotor finds its starting speed: a coast from 125 rad/s under
/// friction alone, then a current pulse.
#[test]
fn the_fit_finds_the_starting_speed() {
    let (j_over_kt, b_over_kt) = (2e-3, 4e-3);
    let iq = |t: f32, _: f32| if t > 0.05 && t < 0.15 { 1.5 } else { 0.0 };
    // The regressors about another speed than the start's: the fit still finds it.
    let f = fit(&spin(0.3, 125.0, j_over_kt, b_over_kt, iq, &|_| 0.0), 100.0).expect("a fit");
    assert!(
        (f.amps_per_accel_a_s2 / j_over_kt - 1.0).abs() < 0.01,
        "{f:?}"
    );
    assert!(f.starts_at(125.0, 125.0), "{f:?}");
    assert!(!f.starts_at(125.0 * (1.0 - 2.0 * START_SPEED_TOLERANCE), 125.0));
}

/// No acceleration (a rotor at one speed all along), no travel, or a rotor that
/// accelerates backwards against its current: no fit.
#[test]
fn without_an_acceleration_there_is_no_fit() {
    let steady = spin(0.4, 100.0, 2e-3, 1e-3, |_, w| 1e-3 * w, &|_| 0.0);
    assert_eq!(fit(&steady, 100.0), None);
    let still = spin(0.4, 0.0, 2e-3, 1e-3, |_, _| 0.0, &|_| 0.0);
    assert_eq!(fit(&still, 0.0), None);
    let backwards: Vec<(f32, f32)> = spin(0.4, 0.0, 2e-3, 0.0, |_, _| 1.0, &|_| 0.0)
        .into_iter()
        .map(|(th, q)| (th, -q))
        .collect();
    assert_eq!(fit(&backwards, 0.0), None);
}

/// Two windows of the coast, id = +I then -I, in a frame 0.3 rad off the rotor's, with
/// R's and the inverter's errors (odd in id) on d and L's on q: ψ within 1e-4.
#[test]
fn the_coasts_two_halves_give_the_flux_whatever_the_frame() {
    let (psi, delta, w) = (0.0123f32, 0.3f32, 120.0f32);
    let mut m = FluxMeter::default();
    let (mut th, mut d, mut q) = (1.0f32, 0.0f32, 0.0f32);
    for sign in [1.0f32, -1.0] {
        for _ in 0..15 {
            m.add(th.rem_euclid(TAU), [d, q]);
            // Back-EMF per mechanical rad (Wb) and the odd terms (V·s per pole pair).
            d += (psi * libm::sinf(delta) * w + sign * 0.4) * DT;
            q += (psi * libm::cosf(delta) * w + sign * 0.05) * DT;
            th += w * DT;
        }
        m.close();
    }
    let found = m.flux_wb().expect("flux");
    assert!((found / psi - 1.0).abs() < 1e-4, "{found}");
    // Too little travel, or nothing back: no flux.
    let mut short = FluxMeter::default();
    short.add(0.0, [0.0; 2]);
    short.add(0.5, [0.0, 0.006]);
    assert_eq!(short.flux_wb(), None);
    let mut none = FluxMeter::default();
    none.add(0.0, [0.0; 2]);
    none.add(3.0, [0.0; 2]);
    assert_eq!(none.flux_wb(), None);
}

#[test]
fn the_probe_finds_the_acceleration_per_amp_from_rest() {
    // 0.5 A on a rotor of 200 rad/s²/A from rest, its angle wrapped and read with a
    // sensor error of 10 mrad at 5 per turn.
    let (amps, per_amp) = (0.5f32, 200.0f32);
    let mut p = Probe::default();
    let mut t = 0.0f32;
    let mut ended = vec![];
    while p.probing() {
        p.next_step();
        let th = 0.5 * amps * per_amp * t * t;
        p.add(
            DT,
            (2.0 + th + 0.01 * (5.0 * th).sin()).rem_euclid(TAU),
            amps,
        );
        ended.extend(p.ended());
        t += DT;
        assert!(t <= PROBE_TIMEOUT_S + 2.0 * DT);
    }
    assert_eq!(ended.len(), 1);
    assert!((ended[0] * per_amp - 1.0).abs() < 0.06, "{ended:?}");
    // It ended on its travel, not its time.
    let t_travel = (2.0 * PROBE_TRAVEL_RAD / (amps * per_amp)).sqrt();
    assert!(
        (p.duration_s() - t_travel).abs() < 2.0 * DT,
        "{}",
        p.duration_s()
    );
    p.next_step();
    assert_eq!(p.ended(), None, "reported once");
}

#[test]
fn a_rotor_that_does_not_turn_gives_the_probe_nothing() {
    for theta in [1.0, f32::NAN] {
        let mut p = Probe::default();
        let mut steps = 0;
        while p.probing() {
            p.next_step();
            p.add(DT, theta, 0.5);
            assert_eq!(p.ended(), None);
            steps += 1;
            assert!(steps as f32 * DT <= PROBE_TIMEOUT_S + 2.0 * DT);
        }
    }
}
