//! The oracle: the exact inverse of the simulated sensor, the floor that noise and
//! quantisation leave to any calibration.

use mras_sim::{wrap_pi, SensorModel, MAX_SENSOR_HARMONICS};

/// Gauss-Newton iterations; started at the true angle with a residual of noise size,
/// two already agree with four to 1e-12 rad.
const ITERATIONS: usize = 3;

/// The sensor-electrical angle θ (in (-π, π]) that explains the sample best: the
/// least-squares fit `min |(x, y) - model(θ)|²` (the maximum-likelihood angle under the
/// simulated white Gaussian noise), with Y evaluated `skew_e_rad` later in electrical
/// angle, as the simulated ADC samples it. Started from the true angle `theta_s_rad`, so
/// it finds the right branch; noiseless samples give that angle back exactly.
pub fn oracle_angle_rad(
    model: &SensorModel,
    skew_e_rad: f64,
    x: f32,
    y: f32,
    theta_s_rad: f64,
) -> f64 {
    // (h, complex amplitude of X, of Y): X = Ax + Re Σ ax_h e^{jhθ},
    // Y = Ay + Im Σ ay_h e^{jh(θ+δ)}.
    let mut terms = [(0i32, (0.0, 0.0), (0.0, 0.0)); MAX_SENSOR_HARMONICS + 1];
    let polar = |b: f64, phi: f64| (b * phi.cos(), b * phi.sin());
    terms[0] = (1, polar(model.bx1, model.phi_x1_rad), (model.by1, 0.0));
    let count = model.harmonic_count.min(MAX_SENSOR_HARMONICS);
    let mut max_order = 1usize;
    for (dst, hm) in terms[1..].iter_mut().zip(&model.harmonics[..count]) {
        *dst = (hm.h, polar(hm.bx, hm.phi_x_rad), polar(hm.by, hm.phi_y_rad));
        max_order = max_order.max(hm.h.unsigned_abs() as usize);
    }
    let terms = &terms[..count + 1];
    let (x, y) = (x as f64, y as f64);
    let mut th = theta_s_rad;
    for _ in 0..ITERATIONS {
        let px = powers(th, max_order);
        let py = powers(th + skew_e_rad, max_order);
        // Value and derivative of X and Y.
        let (mut xv, mut xd, mut yv, mut yd) = (model.ax, 0.0, model.ay, 0.0);
        for &(h, (axr, axi), (ayr, ayi)) in terms {
            let hf = h as f64;
            let (cr, ci) = power(&px, h);
            // ax·e^{jhθ} = (re, im); d/dθ Re(...) = -h·im.
            let (re, im) = (axr * cr - axi * ci, axr * ci + axi * cr);
            xv += re;
            xd -= hf * im;
            let (cr, ci) = power(&py, h);
            let (re, im) = (ayr * cr - ayi * ci, ayr * ci + ayi * cr);
            yv += im;
            yd += hf * re;
        }
        let (ex, ey) = (xv - x, yv - y);
        let curvature = xd * xd + yd * yd;
        if curvature.is_nan() || curvature <= 0.0 {
            break;
        }
        th -= (ex * xd + ey * yd) / curvature;
    }
    wrap_pi(th)
}

/// e^{jiθ} for i = 0..=max (at most 31).
fn powers(th: f64, max: usize) -> [(f64, f64); 32] {
    let mut p = [(1.0, 0.0); 32];
    let (s, c) = th.sin_cos();
    for i in 1..=max.min(31) {
        let (a, b) = p[i - 1];
        p[i] = (a * c - b * s, a * s + b * c);
    }
    p
}

/// e^{jhθ} from the table, conjugated for negative h.
fn power(p: &[(f64, f64); 32], h: i32) -> (f64, f64) {
    let (re, im) = p[(h.unsigned_abs() as usize).min(31)];
    if h < 0 {
        (re, -im)
    } else {
        (re, im)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::accuracy::draw_sensor;

    #[test]
    fn noiseless_samples_invert_exactly_with_skew() {
        let model = draw_sensor(7, 3).params.model;
        let skew = 2e-3;
        let mut worst = 0.0f64;
        for i in 0..2000 {
            let th_m = -3.0 + 0.00371 * i as f64;
            let ts = 2.0 * th_m;
            let x = model.vector(th_m).0;
            let y = model.vector(th_m + skew / 2.0).1;
            // Start off by 20 mrad: the iteration must pull it in.
            let got = oracle_angle_rad(&model, skew, x as f32, y as f32, ts + 0.02);
            // f32 samples: ~1e-7 of quantisation.
            worst = worst.max(wrap_pi(got - ts).abs());
        }
        assert!(worst < 1e-6, "{worst}");
    }
}
