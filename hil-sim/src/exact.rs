//! `f64::round` and `f64::floor` with the same results, bit for bit, without the
//! library call they compile to on baseline x86-64 (no SSE4.1 `roundsd`): the plant
//! rounds its ADC conversions and splits angles into turns every control period.

/// 2^52: from here on every f64 is an integer.
const INTEGRAL: f64 = 4_503_599_627_370_496.0;

/// `x.round()` (half away from zero), as an integer: exactly `x.round() as i64`.
#[inline]
pub fn round_i64(x: f64) -> i64 {
    if x.abs() < INTEGRAL {
        // Truncation is exact in i64 and so is the fraction x - trunc(x). No branch on
        // the fraction: it is noise, and mispredictions would cost more than the call.
        let t = x as i64;
        let f = x - t as f64;
        t + (f >= 0.5) as i64 - (f <= -0.5) as i64
    } else {
        // Integral already, infinite or NaN: the cast saturates as before.
        x.round() as i64
    }
}

/// `x.floor()`, exactly (signed zeros and NaN included).
#[inline]
pub fn floor(x: f64) -> f64 {
    if x.abs() < INTEGRAL {
        let t = x as i64 as f64;
        // floor(x) has the sign of x, -0.0 included.
        (t - (t > x) as u8 as f64).copysign(x)
    } else {
        x.floor()
    }
}

/// `mras_sim::wrap_pi` (to (-π, π]), the same operations with [`floor`] inlined.
#[inline]
pub fn wrap_pi(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let mut r = a - TAU * floor(a / TAU);
    if r > PI {
        r -= TAU;
    } else if r <= -PI {
        r += TAU;
    }
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cases() -> Vec<f64> {
        let mut v = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            -2.5,
            0.49999999999999994,
            -0.49999999999999994,
            0.5000000000000001,
            1e-300,
            -1e-300,
            4503599627370495.5,
            -4503599627370495.5,
            INTEGRAL,
            -INTEGRAL,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::MAX,
            f64::MIN_POSITIVE,
        ];
        // A deterministic sweep of magnitudes and fractions.
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        for _ in 0..200_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let mag = 10f64.powi((s % 40) as i32 - 20);
            let frac = (s >> 11) as f64 / (1u64 << 53) as f64;
            v.push((frac - 0.5) * mag);
            v.push(((s >> 20) % 5000) as f64 * 0.5 - 1250.0);
        }
        v
    }

    #[test]
    fn round_is_the_library_round() {
        for x in cases() {
            assert_eq!(round_i64(x), x.round() as i64, "{x:e}");
        }
    }

    #[test]
    fn wrap_pi_is_the_cores() {
        for x in cases() {
            let (a, b) = (wrap_pi(x), mras_sim::wrap_pi(x));
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{x:e}: {a:e} vs {b:e}"
            );
        }
    }

    #[test]
    fn floor_is_the_library_floor() {
        for x in cases() {
            let (a, b) = (floor(x), x.floor());
            assert!(
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()),
                "{x:e}: {a:e} vs {b:e}"
            );
        }
    }
}
