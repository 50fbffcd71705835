//! The drive board as data: a NUCLEO-G474RE carrying an X-NUCLEO-IHM08M1 three-shunt
//! inverter shield, with an analog sin/cos sensor on Morpho pins the shield leaves free.
//!
//! One description for both sides: the firmware configures its pins, ADC sequence and
//! scaling from it, and the emulator wires its board from it. Every entry names where
//! it comes from (`source`); `tests/st_pin_database.rs` checks each pin against ST's
//! own pin data for the STM32G474RE.
#![no_std]

/// A GPIO pin of the STM32G474RE (LQFP64).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Pin {
    /// Port letter: b'A'..=b'G'.
    pub port: u8,
    pub number: u8,
}

impl Pin {
    pub const fn new(port: u8, number: u8) -> Self {
        Self { port, number }
    }
    /// 0 for port A, 1 for B, ...: the GPIO block index.
    pub const fn port_index(&self) -> usize {
        (self.port - b'A') as usize
    }
}

impl core::fmt::Display for Pin {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "P{}{}", self.port as char, self.number)
    }
}

/// An ADC of the pair sampled in dual injected-simultaneous mode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Adc {
    Adc1,
    Adc2,
}

impl Adc {
    /// 0 for ADC1, 1 for ADC2.
    pub const fn index(&self) -> usize {
        match self {
            Adc::Adc1 => 0,
            Adc::Adc2 => 1,
        }
    }
}

/// TIM1's signals on the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tim1Signal {
    Ch1,
    Ch2,
    Ch3,
    Ch1n,
    Ch2n,
    Ch3n,
    Bkin,
}

impl Tim1Signal {
    /// ST's name of the signal, as in the datasheet's alternate-function table.
    pub const fn name(&self) -> &'static str {
        match self {
            Tim1Signal::Ch1 => "CH1",
            Tim1Signal::Ch2 => "CH2",
            Tim1Signal::Ch3 => "CH3",
            Tim1Signal::Ch1n => "CH1N",
            Tim1Signal::Ch2n => "CH2N",
            Tim1Signal::Ch3n => "CH3N",
            Tim1Signal::Bkin => "BKIN",
        }
    }
}

/// The internal pull of a pin (GPIOx_PUPDR).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pull {
    None,
    Up,
    Down,
}

/// What a pin does on this board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Function {
    /// A TIM1 signal on alternate function `af`.
    Tim1 {
        signal: Tim1Signal,
        af: u8,
        pull: Pull,
    },
    /// An analog input converted by `adc` on `channel`.
    Analog { adc: Adc, channel: u8 },
}

/// What a signal is on the board.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Signal {
    /// Gate-driver inputs of phases U, V, W: high side (HIN) and low side (LIN).
    HighU,
    HighV,
    HighW,
    LowU,
    LowV,
    LowW,
    /// The shield's over-current comparator, active low.
    OverCurrent,
    /// Shunt amplifier outputs of phases U, V, W.
    CurrentU,
    CurrentV,
    CurrentW,
    /// The bus-voltage divider.
    BusVoltage,
    /// The angle sensor's X (cosine) and Y (sine) outputs.
    SensorX,
    SensorY,
}

/// One line of the wiring table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PinUse {
    pub signal: Signal,
    pub pin: Pin,
    pub function: Function,
    /// Where the pin's use on the board is documented.
    pub source: &'static str,
}

const fn tim1(
    signal: Signal,
    port: u8,
    number: u8,
    s: Tim1Signal,
    pull: Pull,
    source: &'static str,
) -> PinUse {
    PinUse {
        signal,
        pin: Pin::new(port, number),
        function: Function::Tim1 {
            signal: s,
            af: 6,
            pull,
        },
        source,
    }
}

const fn analog(
    signal: Signal,
    port: u8,
    number: u8,
    adc: Adc,
    channel: u8,
    source: &'static str,
) -> PinUse {
    PinUse {
        signal,
        pin: Pin::new(port, number),
        function: Function::Analog { adc, channel },
        source,
    }
}

const UM1996: &str = "UM1996 (X-NUCLEO-IHM08M1 user manual), ST morpho connector table";
const SENSOR: &str =
    "this project: a Morpho pin the IHM08M1 leaves unconnected (UM1996), ADC input per DS12288";

/// The board's wiring. To be verified against the sources it names.
pub const PINS: [PinUse; 13] = [
    tim1(Signal::HighU, b'A', 8, Tim1Signal::Ch1, Pull::None, UM1996),
    tim1(Signal::HighV, b'A', 9, Tim1Signal::Ch2, Pull::None, UM1996),
    tim1(Signal::HighW, b'A', 10, Tim1Signal::Ch3, Pull::None, UM1996),
    tim1(Signal::LowU, b'A', 7, Tim1Signal::Ch1n, Pull::None, UM1996),
    tim1(Signal::LowV, b'B', 0, Tim1Signal::Ch2n, Pull::None, UM1996),
    tim1(Signal::LowW, b'B', 1, Tim1Signal::Ch3n, Pull::None, UM1996),
    tim1(
        Signal::OverCurrent,
        b'A',
        6,
        Tim1Signal::Bkin,
        Pull::Up,
        UM1996,
    ),
    analog(Signal::CurrentU, b'A', 0, Adc::Adc1, 1, UM1996),
    analog(Signal::CurrentV, b'C', 1, Adc::Adc2, 7, UM1996),
    analog(Signal::CurrentW, b'C', 0, Adc::Adc1, 6, UM1996),
    analog(Signal::BusVoltage, b'A', 1, Adc::Adc2, 2, UM1996),
    analog(Signal::SensorX, b'B', 12, Adc::Adc1, 11, SENSOR),
    analog(Signal::SensorY, b'C', 4, Adc::Adc2, 5, SENSOR),
];

/// The pin carrying `signal`.
pub const fn pin_use(signal: Signal) -> PinUse {
    let mut i = 0;
    while i < PINS.len() {
        if PINS[i].signal as u8 == signal as u8 {
            return PINS[i];
        }
        i += 1;
    }
    panic!("a signal of the board has no pin");
}

/// The ADC channel of an analog signal.
pub const fn channel(signal: Signal) -> u8 {
    match pin_use(signal).function {
        Function::Analog { channel, .. } => channel,
        Function::Tim1 { .. } => panic!("not an analog signal"),
    }
}

/// The dual injected sequence, slot by slot: (ADC1's signal, ADC2's signal), each pair
/// sampled at the same instant. Currents first, around the counter peak where the low
/// sides conduct; the sensor's X and Y last, together.
pub const INJECTED_SEQUENCE: [(Signal, Signal); 3] = [
    (Signal::CurrentU, Signal::CurrentV),
    (Signal::CurrentW, Signal::BusVoltage),
    (Signal::SensorX, Signal::SensorY),
];

/// Sampling time of each slot, in half ADC clock cycles (13 = 6.5 cycles), and its
/// SMPR encoding (RM0440 §21.7.6): the shunt amplifiers' low-impedance outputs need
/// little; the sensor's bridge amplifier more.
pub const SLOT_SAMPLING_HALF_CYCLES: [u16; 3] = [13, 13, 49];
pub const fn smp_code(half_cycles: u16) -> u8 {
    match half_cycles {
        5 => 0,
        13 => 1,
        25 => 2,
        49 => 3,
        95 => 4,
        185 => 5,
        495 => 6,
        _ => 7,
    }
}

/// The shield's phase-current sensing: shunt, amplifier gain and offset, ADC reference.
pub mod current_sense {
    /// R_shunt (Ω) and the amplifier's gain (V/V): UM1996 and the Motor Control SDK's
    /// board description of the X-NUCLEO-IHM08M1.
    pub const SHUNT_OHM: f32 = 0.010;
    pub const AMPLIFIER_GAIN: f32 = 5.18;
    /// The amplifier's output at zero current (V): biased at mid-supply.
    pub const OFFSET_V: f32 = 1.65;
    /// ADC full scale (V, VREF+ = VDDA on the Nucleo) and counts.
    pub const VREF_V: f32 = 3.3;
    pub const FULL_SCALE_COUNTS: u16 = 4095;
    /// Low-side shunts: a current out of the inverter into the motor flows from ground
    /// up through the shunt while the low side conducts, and reads below the offset.
    pub const SIGN: f32 = -1.0;
    /// Amperes per ADC count, with the sign.
    pub const AMPS_PER_COUNT: f32 =
        SIGN * VREF_V / (FULL_SCALE_COUNTS as f32 + 1.0) / (SHUNT_OHM * AMPLIFIER_GAIN);
    /// The offset in counts.
    pub const ZERO_COUNTS: u16 = (OFFSET_V / VREF_V * (FULL_SCALE_COUNTS as f32 + 1.0)) as u16;
    /// After a low side turns on, the shunt signal settles (switching noise and the
    /// amplifier's rise) for this long before it reads the phase current (ns): the
    /// Motor Control SDK's T_noise/T_rise of the board.
    pub const SETTLE_NS: u32 = 1000;
}

/// The bus-voltage divider: V_bus = V_adc × `RATIO`.
pub mod bus_voltage {
    /// Motor Control SDK board description (BUS_VOLTAGE_CONVERSION_FACTOR, V at full
    /// scale of 3.3 V... see the docs).
    pub const RATIO: f32 = 19.17;
}

/// The shield's over-current protection.
pub mod over_current {
    /// Whether the board pulls the comparator's open-drain output up; if not, the
    /// firmware enables the pin's internal pull-up ([`super::PINS`]).
    pub const BOARD_PULL_UP: bool = false;
}

/// The sensor's analog front end (KMZ41 bridge through an amplifier biased at
/// mid-supply): counts at zero and at the nominal amplitude.
pub mod sensor {
    pub const OFFSET_COUNTS: u16 = 2048;
    pub const AMPLITUDE_COUNTS: u16 = 1600;
}
