//! The drive board as data: a NUCLEO-G474RE carrying an X-NUCLEO-IHM08M1 three-shunt
//! inverter shield, with an analog sin/cos sensor on Morpho pins the shield leaves free.
//!
//! One description for both sides: the firmware configures its pins, ADC sequence and
//! scaling from it, and the emulator wires its board from it. Every entry names where
//! it comes from (`source`); `tests/st_pin_database.rs` checks each pin against ST's
//! own pin data for the STM32G474RE (the `stm32-metapac` crate's metadata, generated
//! from ST's CubeMX database).
//!
//! The sources, and what could not be read first-hand (docs/hardware.md, *Board*):
//! * apache/nuttx `Documentation/platforms/arm/stm32f4/boards/nucleo-f446re/index.rst`,
//!   section *ihm08m1_f32 and ihm08m1_b16*: the IHM08M1's pin table (Morpho signals by
//!   Nucleo-64 pin name), shunt, amplifier gain and sign, bus divider, ratings.
//! * apache/nuttx `boards/arm/stm32/common/src/stm32_ihm08m1.c`: the L6398's fixed dead
//!   time and the inverted polarity its low-side inputs need.
//! * okhsunrog/oxifoc `docs/hw/nucleo-g474re-ihm08m1.md`: the same shield re-derived for
//!   the NUCLEO-G474RE from UM1996 Tables 3/4, the shield's schematic and UM2505
//!   Table 16 (Morpho positions, the 0 Ω links R47..R86, the pins the shield also ties
//!   that must stay high-impedance). UM1996 and UM2505 themselves were not available
//!   as text here: their facts are taken through these two repositories.
//! * ST L6398 datasheet (DocID18199 Rev 4, features list): fixed 320 ns dead time,
//!   interlocking. LIN active low: nuttx's stm32_ihm08m1.c (inverted CHxN) and the ST
//!   community thread "L6398 (IHM08M1) Input Logic Confusion" (the datasheet's truth
//!   table itself was not available as text here).
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
    /// ST's peripheral name.
    pub const fn name(&self) -> &'static str {
        match self {
            Adc::Adc1 => "ADC1",
            Adc::Adc2 => "ADC2",
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
    /// A gate-driver output (not the break input): driven at high speed.
    pub const fn is_output(&self) -> bool {
        !matches!(self, Tim1Signal::Bkin)
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
    /// The NUCLEO-G474RE header position (ST morpho CN7/CN10, Arduino name if any), as
    /// zephyrproject-rtos/zephyr boards/st/nucleo_g474re/{st_morpho,arduino_r3}_connector.dtsi
    /// and oxifoc give them.
    pub connector: &'static str,
    /// Where the pin's use on the board is documented.
    pub source: &'static str,
}

const fn tim1(
    signal: Signal,
    pin: Pin,
    s: Tim1Signal,
    pull: Pull,
    connector: &'static str,
    source: &'static str,
) -> PinUse {
    PinUse {
        signal,
        pin,
        // TIM1's channels and BKIN are AF6 on every pin used here (DS12288 Table 13;
        // checked against ST's data by tests/st_pin_database.rs).
        function: Function::Tim1 {
            signal: s,
            af: 6,
            pull,
        },
        connector,
        source,
    }
}

const fn analog(
    signal: Signal,
    pin: Pin,
    adc: Adc,
    channel: u8,
    connector: &'static str,
    source: &'static str,
) -> PinUse {
    PinUse {
        signal,
        pin,
        function: Function::Analog { adc, channel },
        connector,
        source,
    }
}

const fn p(port: u8, number: u8) -> Pin {
    Pin::new(port, number)
}

/// The board's wiring.
pub const PINS: [PinUse; 13] = [
    tim1(
        Signal::HighU,
        p(b'A', 8),
        Tim1Signal::Ch1,
        Pull::None,
        "CN10-23 (D7)",
        "Phase U high = TIM1_CH1 PA8: nuttx ihm08m1 table; UH CN10-23 via R56: oxifoc (UM1996)",
    ),
    tim1(
        Signal::HighV,
        p(b'A', 9),
        Tim1Signal::Ch2,
        Pull::None,
        "CN10-21 (D8)",
        "Phase V high = TIM1_CH2 PA9: nuttx ihm08m1 table; VH CN10-21 via R64: oxifoc (UM1996)",
    ),
    tim1(
        Signal::HighW,
        p(b'A', 10),
        Tim1Signal::Ch3,
        Pull::None,
        "CN10-33 (D2)",
        "Phase W high = TIM1_CH3 PA10: nuttx ihm08m1 table; WH CN10-33 via R70: oxifoc (UM1996)",
    ),
    tim1(
        Signal::LowU,
        p(b'A', 7),
        Tim1Signal::Ch1n,
        Pull::None,
        "CN10-15 (D11)",
        "Phase U low = TIM1_CH1N PA7: nuttx ihm08m1 table; UL CN10-15 via R58: oxifoc (UM1996)",
    ),
    tim1(
        Signal::LowV,
        p(b'B', 0),
        Tim1Signal::Ch2n,
        Pull::None,
        "CN7-34 (A3)",
        "Phase V low = TIM1_CH2N PB0: nuttx ihm08m1 table; VL CN7-34 via R67: oxifoc (UM1996)",
    ),
    tim1(
        Signal::LowW,
        p(b'B', 1),
        Tim1Signal::Ch3n,
        Pull::None,
        "CN10-24",
        "Phase W low = TIM1_CH3N PB1: nuttx ihm08m1 table; WL CN10-24 via R72: oxifoc (UM1996)",
    ),
    // The comparator's output also reaches PA11 (R73) and PB14 (R74); only PA6 is
    // TIM1_BKIN at AF6 on the G474. Whether the shield pulls it up is not in any source
    // read: the internal pull-up is on (harmless beside an external one).
    tim1(
        Signal::OverCurrent,
        p(b'A', 6),
        Tim1Signal::Bkin,
        Pull::Up,
        "CN10-13 (D12)",
        "BKIN1 PA6: nuttx ihm08m1 table; OCP comparator out CN10-13 via R78: oxifoc (UM1996); \
         pull-up on the shield: not found in a published source",
    ),
    analog(
        Signal::CurrentU,
        p(b'A', 0),
        Adc::Adc1,
        1,
        "CN7-28 (A0)",
        "Current U PA0: nuttx ihm08m1 table; Curr_fdbk_PhA CN7-28 via R47: oxifoc (UM1996); \
         ADC12_IN1: ST data",
    ),
    analog(
        Signal::CurrentV,
        p(b'C', 1),
        Adc::Adc2,
        7,
        "CN7-36 (A4)",
        "Current V PC1: nuttx ihm08m1 table; Curr_fdbk_PhB CN7-36 via R48: oxifoc (UM1996); \
         ADC12_IN7: ST data",
    ),
    analog(
        Signal::CurrentW,
        p(b'C', 0),
        Adc::Adc1,
        6,
        "CN7-38 (A5)",
        "Current W PC0: nuttx ihm08m1 table; Curr_fdbk_PhC CN7-38 via R50: oxifoc (UM1996); \
         ADC12_IN6: ST data",
    ),
    analog(
        Signal::BusVoltage,
        p(b'A', 1),
        Adc::Adc2,
        2,
        "CN7-30 (A1)",
        "VBUS PA1: nuttx ihm08m1 table; VBUS_sensing CN7-30 via R51: oxifoc (UM1996); \
         ADC12_IN2: ST data",
    ),
    // The sensor: the shield's tables (nuttx, oxifoc) connect nothing to PB12, and
    // nuttx drives it as a debug GPIO with this shield fitted.
    analog(
        Signal::SensorX,
        p(b'B', 12),
        Adc::Adc1,
        11,
        "CN10-16",
        "this project: not in the shield's tables (nuttx ihm08m1, oxifoc/UM1996; nuttx uses \
         PB12 as DEBUG0 with this shield); ADC1_IN11: ST data",
    ),
    // Every ADC2 input of the LQFP64 is taken by the shield or the Nucleo (docs:
    // *Sensor wiring*). PA5's link on the shield (R80, to J7) is not mounted; on the
    // Nucleo PA5 drives the green user LED LD2, which must be disconnected.
    analog(
        Signal::SensorY,
        p(b'A', 5),
        Adc::Adc2,
        13,
        "CN10-11 (D13)",
        "this project: shield link R80 to PA5 not mounted (oxifoc/UM1996); Nucleo LD2 on PA5 \
         must be disconnected (UM2505, solder bridge not verified here); ADC2_IN13: ST data",
    ),
];

/// Pins the shield (or the Nucleo) also connects, which the firmware leaves in their
/// reset state (analog, high impedance on the G474): none of them may carry a signal
/// of [`PINS`]. Each with what drives it.
pub const RESERVED: [(Pin, &str); 21] = [
    (
        p(b'A', 11),
        "shield: OCP comparator, second link R73 (TIM1_BKIN2 on the G474)",
    ),
    (
        p(b'B', 14),
        "shield: OCP comparator, third link R74 (TIM1_CH2N on the G474)",
    ),
    (
        p(b'B', 15),
        "shield: UL gate input, second link R86 (TIM1_CH3N on the G474)",
    ),
    (p(b'A', 12), "shield: CPOUT, comparator output R52"),
    (p(b'B', 4), "shield: CURRENT REF (OCP threshold PWM) R77"),
    (p(b'A', 4), "shield: speed potentiometer R181"),
    (p(b'C', 2), "shield: temperature NTC R54"),
    (p(b'C', 3), "shield: BEMF1 divider R59"),
    (p(b'B', 11), "shield: BEMF2 divider R60"),
    (p(b'C', 4), "shield: BEMF2 divider R61"),
    (p(b'C', 5), "shield: BEMF3 divider R65"),
    (p(b'C', 9), "shield: GPIO_BEMF divider enable R55"),
    (p(b'A', 15), "shield: Hall/encoder H1/A R79"),
    (p(b'B', 3), "shield: Hall/encoder H2/B R81"),
    (p(b'B', 10), "shield: Hall/encoder H3/Z R84"),
    (p(b'B', 2), "shield: red LED"),
    (p(b'B', 5), "shield: debug J7-3 R85"),
    (p(b'A', 2), "Nucleo: ST-LINK virtual COM port (LPUART1 TX)"),
    (p(b'A', 3), "Nucleo: ST-LINK virtual COM port (LPUART1 RX)"),
    (p(b'A', 13), "Nucleo: SWDIO"),
    (p(b'A', 14), "Nucleo: SWCLK"),
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
    /// R_shunt (Ω) and the amplifier's gain (V/V): "Current shunt resistance = 0.01",
    /// "Current sense gain = -5.18 (inverted current)" (apache/nuttx
    /// boards/arm/stm32/common/src/stm32_ihm08m1.c and the nucleo-f446re board page).
    /// 51.8 mV/A at the ADC pin.
    pub const SHUNT_OHM: f32 = 0.010;
    pub const AMPLIFIER_GAIN: f32 = 5.18;
    /// The amplifier's output at zero current (V). Not found in a published source read
    /// here (UM1996's figure was not available as text; a third-party note, oxifoc
    /// TODO.md, gives ≈1.71 V): mid-supply is the nominal, the firmware measures the
    /// real zero at every power-up and accepts ±200 counts (±0.16 V) around it.
    pub const OFFSET_V: f32 = 1.65;
    /// ADC full scale (V, VREF+ = VDDA = 3.3 V on the Nucleo) and counts.
    pub const VREF_V: f32 = 3.3;
    pub const FULL_SCALE_COUNTS: u16 = 4095;
    /// Low-side shunts: a current out of the inverter into the motor flows from ground
    /// up through the shunt while the low side conducts, and reads below the offset
    /// (nuttx: gain -5.18, "inverted current"; IPHASE_RATIO = -19.3 A/V).
    pub const SIGN: f32 = -1.0;
    /// Amperes per ADC count, with the sign: -3.3 / 4096 / 0.0518 = -0.01555 A.
    pub const AMPS_PER_COUNT: f32 =
        SIGN * VREF_V / (FULL_SCALE_COUNTS as f32 + 1.0) / (SHUNT_OHM * AMPLIFIER_GAIN);
    /// The offset in counts.
    pub const ZERO_COUNTS: u16 = (OFFSET_V / VREF_V * (FULL_SCALE_COUNTS as f32 + 1.0)) as u16;
    /// The range either side of the offset before the ADC clips (A): 1.65 V / 51.8 mV/A
    /// = 31.9 A, three times the drive's I_MAX_A of 10 A (1.59 V / 51.8 mV/A = 30.7 A
    /// were the offset 1.71 V).
    pub const RANGE_A: f32 = OFFSET_V / (SHUNT_OHM * AMPLIFIER_GAIN);
    /// After a low side turns on, the shunt signal settles (switching noise and the
    /// amplifier's rise) for this long before it reads the phase current (ns). The
    /// Motor Control SDK's T_noise/T_rise for this board were not found in a published
    /// source: 1 µs is this project's assumption, to be measured (docs/hardware.md).
    pub const SETTLE_NS: u32 = 1000;
}

/// The bus-voltage divider: V_bus = V_adc × `RATIO`.
pub mod bus_voltage {
    /// 169 kΩ over 9.31 kΩ: "Vbus sense gain = 9.31k/(9.31k+169k) = 0.0522", VBUS_RATIO
    /// 19.152 (apache/nuttx nucleo-f446re board page, ihm08m1; the same divider in
    /// okhsunrog/oxifoc docs/hw/nucleo-g474re-ihm08m1.md). 48 V reads 2.51 V.
    pub const RATIO: f32 = (169.0e3 + 9.31e3) / 9.31e3;
}

/// The gate drivers (L6398, one per half bridge).
pub mod gate_driver {
    /// LIN is active low (LIN = 0 turns the low side on): TIM1's CHxN must be inverted
    /// (CCxNP = 1) and idle high (OISxN = 1) for the low sides to be off with MOE = 0.
    /// apache/nuttx boards/arm/stm32/common/src/stm32_ihm08m1.c refuses any other
    /// configuration ("PWM complementary channels must have inverted polarity"); ST's
    /// community thread on the IHM08M1's L6398 reads the truth table the same way
    /// (HIN = LIN = 1: high side on; HIN = LIN = 0: low side on). HIN is active high.
    /// The L6398 datasheet's truth table itself was not read here.
    pub const LOW_SIDE_INPUT_ACTIVE_LOW: bool = true;
    /// The L6398's own dead time and interlock (ns): HIN and LIN asking for both sides
    /// turn both off, and each turn-on waits this long after the other side's turn-off.
    /// TIM1's dead time adds to it.
    pub const INTERNAL_DEAD_TIME_NS: u32 = 320;
}

/// The motor the firmware's constants describe (ElectroCraft RP34 class, the paper's
/// bench motor), and the bench supply: where a drive starts before it identifies its
/// motor. The identification (`drive::ident` in the firmware) replaces R and L at
/// every power-up; the rest are used as they are.
pub mod motor {
    pub const POLE_PAIRS: u16 = 4;
    pub const R_OHM: f32 = 0.3;
    pub const L_H: f32 = 0.5e-3;
    pub const FLUX_WB: f32 = 0.02;
    pub const INERTIA_KG_M2: f32 = 2.0e-4;
    pub const VDC_V: f32 = 24.0;
    pub const I_MAX_A: f32 = 10.0;
}

/// The shield's over-current protection.
pub mod over_current {
    /// Whether the board pulls the comparator's output up. Not found in a published
    /// source read here: `false` makes the firmware enable the pin's internal pull-up
    /// ([`super::PINS`]), harmless if the board has one too.
    pub const BOARD_PULL_UP: bool = false;
}

/// The sensor's analog front end (KMZ41 bridge through an amplifier biased at
/// mid-supply, this project's): counts at zero and at the nominal amplitude.
pub mod sensor {
    pub const OFFSET_COUNTS: u16 = 2048;
    pub const AMPLITUDE_COUNTS: u16 = 1600;
}
