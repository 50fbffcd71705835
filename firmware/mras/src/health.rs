//! Faults: each has its own bit; they latch until [`crate::Tracker::clear_faults`].

/// Why a sample was rejected or the observer is no longer trustworthy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// NaN or ±inf in x, y or the torque feedforward. Sample dropped, state held.
    NonFiniteInput,
    /// |Z| below `health.amplitude_min`: sensor disconnected or unpowered. Sample dropped.
    SensorLost,
    /// |Z| above `health.amplitude_max`, or a railed ADC channel (refused by the front end
    /// through `Tracker::refuse`). Sample dropped.
    SensorSaturated,
    /// The decoupled vector and the reference are more than `health.lock_threshold_rad`
    /// apart: the observer may slip a sensor period. Reported once per loss; the core
    /// re-acquires by itself and adaptation pauses until it has.
    LossOfLock,
    /// An update would have produced a non-finite state (absurd torque input). Held.
    NumericalOverflow,
}

impl Fault {
    const fn bit(self) -> u8 {
        1 << self as u8
    }

    pub const ALL: [Fault; 5] = [
        Fault::NonFiniteInput,
        Fault::SensorLost,
        Fault::SensorSaturated,
        Fault::LossOfLock,
        Fault::NumericalOverflow,
    ];
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Fault::NonFiniteInput => "non-finite input sample",
            Fault::SensorLost => "sensor amplitude too low (disconnected?)",
            Fault::SensorSaturated => "sensor amplitude too high or ADC railed",
            Fault::LossOfLock => "observer lost lock",
            Fault::NumericalOverflow => "state update would overflow",
        })
    }
}

/// A latched set of faults (one bit each; `bits()` is what goes over the wire).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults(u8);

impl Faults {
    pub fn insert(&mut self, f: Fault) {
        self.0 |= f.bit();
    }
    pub fn contains(self, f: Fault) -> bool {
        self.0 & f.bit() != 0
    }
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
    pub fn bits(self) -> u8 {
        self.0
    }
    pub fn iter(self) -> impl Iterator<Item = Fault> {
        Fault::ALL.into_iter().filter(move |f| self.contains(*f))
    }
}
