//! The identification against an R-L load behind an inverter with dead time and device
//! drops, sampled by a quantizing current sense, across the drive's ratings.

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
}

impl Load {
    fn new(r: f64, l: f64, v_err: f64) -> Self {
        Self {
            r,
            l,
            v_err,
            i: [0.0; 2],
            pending: [0.0; 2],
            sign: [1.0; 3],
        }
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
            for (k, ve) in [ea, eb].into_iter().enumerate() {
                let u = applied[k] + ve;
                self.i[k] = a * self.i[k] + (1.0 - a) * u / self.r;
            }
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
        let v = id.step(load.measured());
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
