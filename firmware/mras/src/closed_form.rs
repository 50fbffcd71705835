//! The paper's closed-form decoupling coefficients for single-error sensors, as test
//! oracles and for reports. Unit fundamental (B_y1 = 1) unless stated; f64.

/// Eq. (6)-(7): offset vector that removes offsets (Ax, Ay) and an equal x/y second
/// harmonic B2·e^{j(2θs+φ2)}. Returns (Xo, Yo).
pub fn offset_and_h2(ax: f64, ay: f64, b2: f64, phi2_rad: f64) -> (f64, f64) {
    (
        -ax + b2 * libm::cos(phi2_rad),
        -ay - b2 * libm::sin(phi2_rad),
    )
}

/// Eq. (10)-(11): X-only (C, D) that make X = B_x1·cos(θs+φx1) + C cos θs + D sin θs
/// equal B_y1·cos θs.
pub fn amplitude_quadrature(bx1: f64, by1: f64, phi_x1_rad: f64) -> (f64, f64) {
    let c = by1 * (1.0 - libm::cos(phi_x1_rad)) + (by1 - bx1) * libm::cos(phi_x1_rad);
    let d = bx1 * libm::sin(phi_x1_rad);
    (c, d)
}

/// Eq. (13)-(15): (C, D) that remove an equal x/y third harmonic B3·e^{j(3θs+φ3)}, and
/// the constant residual angle ψ (sensor electrical; the paper's 2φ_err) it leaves.
/// Eq. (13), `sin ψ = B3 sin(φ3 - 3ψ)`, is solved by Newton's method.
pub fn third_harmonic(b3: f64, phi3_rad: f64) -> (f64, f64, f64) {
    let mut psi = 0.0;
    for _ in 0..50 {
        let a = phi3_rad - 3.0 * psi;
        let f = libm::sin(psi) - b3 * libm::sin(a);
        let df = libm::cos(psi) + 3.0 * b3 * libm::cos(a);
        let step = f / df;
        psi -= step;
        if libm::fabs(step) < 1e-15 {
            break;
        }
    }
    let a = phi3_rad - 3.0 * psi;
    (2.0 * b3 * libm::cos(a), -2.0 * b3 * libm::sin(a), psi)
}

/// Eq. (19)-(20), literally: E = sqrt(B²/(1+tan²φ)), F = -sqrt(B² - E²). Valid as
/// printed for φ in [0, π/2]; the general form is E + jF = B·e^{-jφ}.
pub fn harmonic_ef(b: f64, phi_rad: f64) -> (f64, f64) {
    let t = libm::tan(phi_rad);
    let e = libm::sqrt(b * b / (1.0 + t * t));
    let f = -libm::sqrt((b * b - e * e).max(0.0));
    (e, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn third_harmonic_reduces_to_first_order() {
        let (c, d, psi) = third_harmonic(0.001, 0.7);
        assert!((c - 0.002 * libm::cos(0.7)).abs() < 1e-5);
        assert!((d + 0.002 * libm::sin(0.7)).abs() < 1e-5);
        assert!((psi - 0.001 * libm::sin(0.7)).abs() < 1e-5);
    }

    #[test]
    fn ef_matches_general_form_in_first_quadrant() {
        let (e, f) = harmonic_ef(0.03, 0.4);
        assert!((e - 0.03 * libm::cos(0.4)).abs() < 1e-12);
        assert!((f + 0.03 * libm::sin(0.4)).abs() < 1e-12);
    }
}
