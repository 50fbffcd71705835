//! ADC counts → the core's scaled sensor units.
//!
//! The sensor's X and Y arrive as 12-bit counts (RM0440 §21: right-aligned, 0..=4095).
//! The scaling `x = (counts - offset) · gain` is configured as a fixed-point gain (I2F30)
//! and applied as one f32 multiplication by that gain rounded to f32 once: within an ulp
//! of the exact value, identical on every target, and free of the soft 64-bit integer
//! conversion an exact product would need in the control interrupt. Counts at the rails
//! mean a saturated front end.

use fixed::types::I2F30;

/// Full scale of the 12-bit ADC.
pub const ADC_MAX_COUNTS: u16 = 4095;

/// Per-channel nominal scaling, e.g. from the sensor's datasheet or a bench measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelScaling {
    /// Counts at the channel's zero (mid-supply for a KMZ41 bridge amplifier).
    pub offset_counts: u16,
    /// Scaled units per count.
    pub gain: I2F30,
    /// The converter's largest count (0 and this are the rails).
    pub max_counts: u16,
    /// `gain` as f32, what the control path multiplies by.
    gain_f32: f32,
}

impl ChannelScaling {
    /// From a nominal amplitude (the counts that correspond to a unit vector), for the
    /// 12-bit converter.
    pub fn from_amplitude(offset_counts: u16, amplitude_counts: u16) -> Option<Self> {
        if amplitude_counts == 0 || offset_counts > ADC_MAX_COUNTS {
            return None;
        }
        // 1/amplitude, rounded to the nearest 2^-30 (integer arithmetic: no panics).
        let a = amplitude_counts as i64;
        let gain = I2F30::from_bits((((1i64 << 30) + a / 2) / a) as i32);
        Some(Self {
            offset_counts,
            gain,
            max_counts: ADC_MAX_COUNTS,
            gain_f32: gain.to_num(),
        })
    }

    /// From the size of one count in scaled units, for a converter of `bits` bits
    /// (1..=16) with its zero at mid-scale. `None` if the count size is not
    /// representable (≤ 0, ≥ 2, or not finite).
    pub fn from_count_size(count_size: f64, bits: u8) -> Option<Self> {
        if !((1..=16).contains(&bits) && count_size > 0.0 && count_size < 2.0) {
            return None;
        }
        let max_counts = ((1u32 << bits) - 1) as u16;
        let gain = I2F30::checked_from_num(count_size)?;
        Some(Self {
            offset_counts: (1u32 << (bits - 1)) as u16,
            gain,
            max_counts,
            gain_f32: gain.to_num(),
        })
    }
}

/// Why a pair of samples is not usable.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleError {
    /// A channel sits at 0 or full scale: saturated amplifier or open input.
    Railed,
    /// A count above 12 bits: a misconfigured ADC (wrong resolution or alignment).
    OutOfRange,
}

/// Scale one channel: the count difference (17 bits, exact in f32) times the gain.
#[inline]
pub fn scale(counts: u16, s: &ChannelScaling) -> Result<f32, SampleError> {
    if counts > s.max_counts {
        return Err(SampleError::OutOfRange);
    }
    if counts == 0 || counts == s.max_counts {
        return Err(SampleError::Railed);
    }
    let d = counts as i32 - s.offset_counts as i32;
    Ok(d as f32 * s.gain_f32)
}

/// The pair's scaling as a stored calibration's hash covers it (offsets in counts, the
/// gains the control path multiplies by).
pub fn record_scaling(x: &ChannelScaling, y: &ChannelScaling) -> calib_record::InputScaling {
    calib_record::InputScaling {
        offset_x: x.offset_counts as f32,
        offset_y: y.offset_counts as f32,
        gain_x: x.gain_f32,
        gain_y: y.gain_f32,
    }
}

/// Scale the (X, Y) pair sampled at the same instant.
#[inline]
pub fn scale_pair(
    x_counts: u16,
    y_counts: u16,
    sx: &ChannelScaling,
    sy: &ChannelScaling,
) -> Result<(f32, f32), SampleError> {
    Ok((scale(x_counts, sx)?, scale(y_counts, sy)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mid_scale_is_zero_and_amplitude_is_one() {
        let s = ChannelScaling::from_amplitude(2048, 1600).unwrap();
        assert_eq!(scale(2048, &s), Ok(0.0));
        let one = scale(2048 + 1600, &s).unwrap();
        assert!((one - 1.0).abs() < 1e-4, "{one}");
        let minus = scale(2048 - 1600, &s).unwrap();
        assert!((minus + 1.0).abs() < 1e-4, "{minus}");
    }

    #[test]
    fn every_count_scales_monotonically_within_an_ulp() {
        let s = ChannelScaling::from_amplitude(2000, 1500).unwrap();
        let mut last = f32::NEG_INFINITY;
        for c in 1..ADC_MAX_COUNTS {
            let v = scale(c, &s).unwrap();
            assert!(v > last);
            // Two roundings (the gain to f32, the product): within an ulp of the rational
            // value.
            let exact = (c as f64 - 2000.0) * s.gain.to_num::<f64>();
            assert!((v as f64 - exact).abs() <= exact.abs() * f32::EPSILON as f64 + 1e-12);
            last = v;
        }
    }

    #[test]
    fn rails_and_garbage_are_refused() {
        let s = ChannelScaling::from_amplitude(2048, 1600).unwrap();
        assert_eq!(scale(0, &s), Err(SampleError::Railed));
        assert_eq!(scale(4095, &s), Err(SampleError::Railed));
        assert_eq!(scale(4096, &s), Err(SampleError::OutOfRange));
        assert_eq!(scale(u16::MAX, &s), Err(SampleError::OutOfRange));
        assert_eq!(scale_pair(100, 4095, &s, &s), Err(SampleError::Railed));
        assert!(ChannelScaling::from_amplitude(2048, 0).is_none());
        assert!(ChannelScaling::from_amplitude(5000, 100).is_none());
    }

    #[test]
    fn count_size_scaling_is_exact_for_binary_fractions_and_checks_its_range() {
        // 3/4096 (a ±1.5 range at 12 bits) is exact in I2F30: counts scale exactly.
        let s = ChannelScaling::from_count_size(3.0 / 4096.0, 12).unwrap();
        assert_eq!((s.offset_counts, s.max_counts), (2048, 4095));
        assert_eq!(scale(2048 + 1365, &s), Ok((1365.0 * 3.0 / 4096.0) as f32));
        assert_eq!(scale(4095, &s), Err(SampleError::Railed));
        let s16 = ChannelScaling::from_count_size(1.0 / 16384.0, 16).unwrap();
        assert_eq!(s16.max_counts, 65535);
        assert_eq!(scale(65534, &s16), Ok(32766.0 / 16384.0));
        assert!(ChannelScaling::from_count_size(0.0, 12).is_none());
        assert!(ChannelScaling::from_count_size(f64::NAN, 12).is_none());
        assert!(ChannelScaling::from_count_size(1e-3, 17).is_none());
    }
}
