//! The identification against an R-L load behind an inverter with dead time and device
//! drops, sampled by a quantizing current sense, across the drive's ratings; and against
//! a winding whose rotor rests anywhere, swinging onto the identification's current.

use drive::ident::{IdentConfig, IdentError, IdentStatus, Identifier};

const T_S: f32 = 50e-6;
/// The board's current count (A).
const COUNT_A: f64 = 0.01555;

/// A stationary rotor's windings in αβ: the exact R-L response over 20 substeps a
/// period, the voltage commanded in a period applied in the next, each phase's voltage
/// short by `v_err·sign(i)` (dead time and device drops), linear across the band in
/// which the PWM ripple takes the current through zero.
struct Load {
    r: f64,
    l: f64,
    v_err: f64,
    i: [f64; 2],
    pending: [f64; 2],
    /// Measured current sign per phase (+1: right).
    sign: [f64; 3],
    /// A free rotor (4 pole pairs): flux linkage (0: none, the rotor stays), inertia,
    /// mechanical angle and speed.
    psi: f64,
    j: f64,
    theta: f64,
    omega: f64,
}

const POLE_PAIRS: f64 = 4.0;
/// The sensor's periods per revolution and its converter's count (scaled units).
const SENSOR_PERIODS: f64 = 2.0;
const SENSOR_COUNT: f64 = 7.3e-4;

impl Load {
    fn new(r: f64, l: f64, v_err: f64) -> Self {
        Self {
            r,
            l,
            v_err,
            i: [0.0; 2],
            pending: [0.0; 2],
            sign: [1.0; 3],
            psi: 0.0,
            j: 1.0,
            theta: 0.0,
            omega: 0.0,
        }
    }

    /// With a rotor of `psi` and `j` resting at `theta_e_deg` electrical from α.
    fn with_rotor(mut self, psi: f64, j: f64, theta_e_deg: f64) -> Self {
        self.psi = psi;
        self.j = j;
        self.theta = theta_e_deg.to_radians() / POLE_PAIRS;
        self
    }

    /// The sensor's vector, quantized.
    fn sensor(&self) -> (f32, f32) {
        let q = |v: f64| ((v / SENSOR_COUNT).round() * SENSOR_COUNT) as f32;
        let a = SENSOR_PERIODS * self.theta;
        (q(a.cos()), q(a.sin()))
    }

    fn phases(i: [f64; 2]) -> [f64; 3] {
        let s3 = 3f64.sqrt();
        [
            i[0],
            -0.5 * i[0] + 0.5 * s3 * i[1],
            -0.5 * i[0] - 0.5 * s3 * i[1],
        ]
    }

    fn measured(&self) -> (f32, f32) {
        let p = Self::phases(self.i);
        let q = |k: usize| (self.sign[k] * p[k] / COUNT_A).round() * COUNT_A;
        let (a, b) = (q(0), q(1));
        (a as f32, ((a + 2.0 * b) / 3f64.sqrt()) as f32)
    }

    fn advance(&mut self, v: (f32, f32)) {
        let applied = self.pending;
        self.pending = [v.0 as f64, v.1 as f64];
        // The inverter's error, per phase, over the band the PWM ripple crosses zero in
        // (at least what keeps the substeps stable).
        const SUB: u32 = 20;
        let (t, h) = (T_S as f64, T_S as f64 / SUB as f64);
        let vmag = applied[0].hypot(applied[1]);
        let i0 = (vmag * t / (2.0 * self.l))
            .max(4.0 * h * self.v_err / self.l)
            .max(1e-3);
        let a = (-self.r * h / self.l).exp();
        for _ in 0..SUB {
            let e = Self::phases(self.i).map(|i| -self.v_err * (i / i0).clamp(-1.0, 1.0));
            let ea = 2.0 / 3.0 * (e[0] - 0.5 * (e[1] + e[2]));
            let eb = (e[1] - e[2]) / 3f64.sqrt();
            // The rotor's back-EMF, jωe·ψ at θe, and its torque.
            let (s, c) = (POLE_PAIRS * self.theta).sin_cos();
            let we = POLE_PAIRS * self.omega;
            let back = [-we * self.psi * s, we * self.psi * c];
            for (k, ve) in [ea, eb].into_iter().enumerate() {
                let u = applied[k] + ve - back[k];
                self.i[k] = a * self.i[k] + (1.0 - a) * u / self.r;
            }
            let torque = 1.5 * POLE_PAIRS * self.psi * (self.i[1] * c - self.i[0] * s);
            self.omega += torque / self.j * h;
            self.theta += self.omega * h;
        }
    }
}

fn cfg() -> IdentConfig {
    IdentConfig {
        current_a: 2.0,
        v_max_v: 24.0 / 3f32.sqrt(),
        i_limit_a: 10.0,
        period_s: T_S,
    }
}

fn run(load: &mut Load) -> (IdentStatus, f32) {
    let mut id = Identifier::new(cfg());
    let mut t = 0.0;
    while id.status() == IdentStatus::Pending && t < 5.0 {
        let v = id.step(load.measured(), load.sensor());
        load.advance(v);
        t += T_S;
    }
    (id.status(), t)
}

#[test]
fn r_and_l_across_the_ratings_with_the_inverters_error() {
    // 0.5 µs of dead time at 20 kHz on 24 V, plus a 0.1 V device drop.
    let v_err = 24.0 * 0.5e-6 / 50e-6 + 0.1;
    for r in [0.05, 0.2, 0.3, 2.0] {
        for l in [20e-6, 0.2e-3, 0.5e-3, 2e-3] {
            // L/R under two periods: the current follows each period's voltage within
            // it, the samples hardly see L (and no loop at this rate needs it).
            if l / r < 2.0 * T_S as f64 {
                continue;
            }
            let mut load = Load::new(r, l, v_err);
            let (s, t) = run(&mut load);
            let IdentStatus::Done(x) = s else {
                panic!("R {r} L {l}: {s:?} after {t} s")
            };
            let er = x.r_ohm as f64 / r - 1.0;
            let ed = x.ld_h as f64 / l - 1.0;
            let eq = x.lq_h as f64 / l - 1.0;
            println!(
                "R {r:5} L {:7.1} µH: R {:+.2} %, Ld {:+.2} %, Lq {:+.2} %, V_inv {:.3} V, {:.3} s",
                l * 1e6,
                100.0 * er,
                100.0 * ed,
                100.0 * eq,
                x.v_inverter_v,
                t
            );
            assert!(er.abs() < 0.05 && ed.abs() < 0.10 && eq.abs() < 0.10);
        }
    }
}

#[test]
fn a_reversed_current_sense_is_refused_by_name() {
    let mut load = Load::new(0.3, 0.5e-3, 0.3);
    load.sign = [-1.0; 3];
    assert_eq!(
        run(&mut load).0,
        IdentStatus::Failed(IdentError::CurrentSign)
    );
}

#[test]
fn a_resistance_the_voltage_cannot_drive_is_refused_by_name() {
    let mut load = Load::new(20.0, 2e-3, 0.3);
    assert_eq!(
        run(&mut load).0,
        IdentStatus::Failed(IdentError::CurrentNotReached)
    );
}

/// A rotor resting off α swings onto the identification's current, lightly damped, for
/// longer than the identification lasts; its back-EMF is not in the levels' means (their
/// windows close where the sensor reads as it did at their start): R within 2 % and L
/// within 10 % from 10° to 160° electrical on a slow heavy rotor and a faster one, and up
/// to 69° (the emulated board's rest) on a light one, with 0.5 µs of dead time and a
/// 0.1 V drop. (The light one released further out is spun round by the loops, whose lag
/// damps the swing negatively at its frequency; R comes out right, but the probe's open
/// loop pulses can then end in an over-current.)
#[test]
fn r_of_a_rotor_left_anywhere_swinging_onto_the_current() {
    let v_err = 24.0 * 0.5e-6 / 50e-6 + 0.1;
    let anywhere = [10.0, 40.0, 69.0, 95.0, 120.0, 160.0];
    for (r, l, psi, j, rest) in [
        (1.8, 1.5e-3, 12e-3, 5e-4, &anywhere[..]),
        (0.081, 31.8e-6, 14.3e-3, 6.3e-4, &anywhere[..]),
        (0.2, 30e-6, 8e-3, 1e-4, &anywhere[..3]),
    ] {
        for &deg in rest {
            let mut load = Load::new(r, l, v_err).with_rotor(psi, j, deg);
            let (s, t) = run(&mut load);
            let IdentStatus::Done(x) = s else {
                panic!("R {r} L {l} at {deg}°: {s:?} after {t} s")
            };
            let er = x.r_ohm as f64 / r - 1.0;
            let (ed, eq) = (x.ld_h as f64 / l - 1.0, x.lq_h as f64 / l - 1.0);
            println!(
                "R {r} L {:.1} µH ψ {psi} J {j} at {deg:>3}°: R {:+.2} %, Ld {:+.2} %, Lq {:+.2} %, {:.3} s, rotor at {:.1}° moving {:.2} rad/s",
                l * 1e6,
                100.0 * er,
                100.0 * ed,
                100.0 * eq,
                t,
                (POLE_PAIRS * load.theta).to_degrees(),
                load.omega
            );
            assert!(er.abs() < 0.02, "R {r} at {deg}°: {er:+.4}");
            assert!(
                ed.abs() < 0.10 && eq.abs() < 0.10,
                "L {l} at {deg}°: {ed:+.4} {eq:+.4}"
            );
        }
    }
}
