//! The board's pin table against ST's own pin data for the STM32G474RE: the
//! `stm32-metapac` crate's metadata (generated from ST's CubeMX database through
//! embassy-rs/stm32-data), `peripherals[].pins[]` = {pin, signal, af}.
//!
//! [`check`] returns every rule a table breaks; the real [`PINS`] must break none, and
//! each mutated copy below must break the rule it was made to break.

use board_map::{
    Adc, Function, Pin, PinUse, Pull, Signal, Tim1Signal, INJECTED_SEQUENCE, PINS, RESERVED,
};
use stm32_metapac::metadata::{Metadata, METADATA};

/// A rule of the board a pin table breaks.
#[derive(Clone, Debug, PartialEq)]
enum PinError {
    /// The pin is not a pin of the chip's package (LQFP64).
    NotInPackage { signal: Signal, pin: String },
    /// ST's data has no TIM1 `signal` on this pin at all.
    NoSuchTim1Signal {
        signal: Signal,
        pin: String,
        tim1: &'static str,
    },
    /// ST's data has the TIM1 signal on this pin, at another alternate function.
    WrongAf {
        signal: Signal,
        pin: String,
        tim1: &'static str,
        af: u8,
        st_af: Vec<u8>,
    },
    /// The pin is not input `channel` of `adc` in ST's data.
    NotAnAdcInput {
        signal: Signal,
        pin: String,
        adc: &'static str,
        channel: u8,
    },
    /// Two lines of the table use one pin.
    DuplicatePin {
        pin: String,
        first: Signal,
        second: Signal,
    },
    /// A signal of the board appears on no line, or on several.
    SignalCount { signal: Signal, count: usize },
    /// A slot's first signal is not converted by ADC1, or its second not by ADC2.
    SlotOnWrongAdc {
        slot: usize,
        signal: Signal,
        expected: &'static str,
    },
    /// A slot's signal is not an analog line of the table.
    SlotNotAnalog { slot: usize, signal: Signal },
    /// Both ADCs would sample the same channel in one slot (RM0440: in dual mode a
    /// channel is not converted by both ADCs at once).
    SameChannelInSlot { slot: usize, channel: u8 },
    /// A signal sits on a pin the shield or the Nucleo drives ([`RESERVED`]).
    ReservedPin {
        signal: Signal,
        pin: String,
        user: &'static str,
    },
    /// The break input must be pulled up before it becomes AF (never floats low).
    BreakNotPulledUp { pin: String },
}

const ALL_SIGNALS: [Signal; 13] = [
    Signal::HighU,
    Signal::HighV,
    Signal::HighW,
    Signal::LowU,
    Signal::LowV,
    Signal::LowW,
    Signal::OverCurrent,
    Signal::CurrentU,
    Signal::CurrentV,
    Signal::CurrentW,
    Signal::BusVoltage,
    Signal::SensorX,
    Signal::SensorY,
];

fn name(pin: Pin) -> String {
    pin.to_string()
}

fn peripheral_pins(
    db: &Metadata,
    peripheral: &str,
) -> &'static [stm32_metapac::metadata::PeripheralPin] {
    db.peripherals
        .iter()
        .find(|p| p.name == peripheral)
        .unwrap_or_else(|| panic!("{peripheral} not in ST's data"))
        .pins
}

/// Every rule `pins` and `sequence` break against ST's data `db` and the reserved pins.
fn check(
    db: &Metadata,
    pins: &[PinUse],
    sequence: &[(Signal, Signal)],
    reserved: &[(Pin, &'static str)],
) -> Vec<PinError> {
    let mut errors = Vec::new();
    let tim1 = peripheral_pins(db, "TIM1");
    for u in pins {
        let pin = name(u.pin);
        if !db.pins.iter().any(|p| p.name == pin) {
            errors.push(PinError::NotInPackage {
                signal: u.signal,
                pin: pin.clone(),
            });
        }
        match u.function {
            Function::Tim1 { signal, af, pull } => {
                let st_af: Vec<u8> = tim1
                    .iter()
                    .filter(|p| p.pin == pin && p.signal == signal.name())
                    .filter_map(|p| p.af)
                    .collect();
                if st_af.is_empty() {
                    errors.push(PinError::NoSuchTim1Signal {
                        signal: u.signal,
                        pin: pin.clone(),
                        tim1: signal.name(),
                    });
                } else if !st_af.contains(&af) {
                    errors.push(PinError::WrongAf {
                        signal: u.signal,
                        pin: pin.clone(),
                        tim1: signal.name(),
                        af,
                        st_af,
                    });
                }
                if signal == Tim1Signal::Bkin && pull != Pull::Up {
                    errors.push(PinError::BreakNotPulledUp { pin: pin.clone() });
                }
            }
            Function::Analog { adc, channel } => {
                let input = format!("IN{channel}");
                let ok = peripheral_pins(db, adc.name())
                    .iter()
                    .any(|p| p.pin == pin && p.signal == input && p.af.is_none());
                if !ok {
                    errors.push(PinError::NotAnAdcInput {
                        signal: u.signal,
                        pin: pin.clone(),
                        adc: adc.name(),
                        channel,
                    });
                }
            }
        }
        if let Some((_, user)) = reserved.iter().find(|(r, _)| *r == u.pin) {
            errors.push(PinError::ReservedPin {
                signal: u.signal,
                pin: pin.clone(),
                user,
            });
        }
    }
    for (i, a) in pins.iter().enumerate() {
        for b in &pins[i + 1..] {
            if a.pin == b.pin {
                errors.push(PinError::DuplicatePin {
                    pin: name(a.pin),
                    first: a.signal,
                    second: b.signal,
                });
            }
        }
    }
    for signal in ALL_SIGNALS {
        let count = pins.iter().filter(|u| u.signal == signal).count();
        if count != 1 {
            errors.push(PinError::SignalCount { signal, count });
        }
    }
    let analog = |signal: Signal| {
        pins.iter()
            .find(|u| u.signal == signal)
            .and_then(|u| match u.function {
                Function::Analog { adc, channel } => Some((adc, channel)),
                Function::Tim1 { .. } => None,
            })
    };
    for (slot, &(first, second)) in sequence.iter().enumerate() {
        let mut channels = [None, None];
        for (k, (signal, expected)) in [(first, Adc::Adc1), (second, Adc::Adc2)]
            .into_iter()
            .enumerate()
        {
            match analog(signal) {
                None => errors.push(PinError::SlotNotAnalog { slot, signal }),
                Some((adc, channel)) => {
                    if adc != expected {
                        errors.push(PinError::SlotOnWrongAdc {
                            slot,
                            signal,
                            expected: expected.name(),
                        });
                    }
                    channels[k] = Some(channel);
                }
            }
        }
        if let [Some(a), Some(b)] = channels {
            if a == b {
                errors.push(PinError::SameChannelInSlot { slot, channel: a });
            }
        }
    }
    errors
}

fn check_board(pins: &[PinUse]) -> Vec<PinError> {
    check(&METADATA, pins, &INJECTED_SEQUENCE, &RESERVED)
}

/// A copy of the board with `signal`'s line replaced.
fn mutated(signal: Signal, f: impl FnOnce(&mut PinUse)) -> Vec<PinUse> {
    let mut pins = PINS.to_vec();
    f(pins.iter_mut().find(|u| u.signal == signal).unwrap());
    pins
}

#[test]
fn st_data_is_the_stm32g474re() {
    assert_eq!(METADATA.name, "STM32G474RE");
    // The LQFP64's 52 I/Os, PG10 (NRST) included.
    assert_eq!(METADATA.pins.len(), 52);
}

#[test]
fn the_board_breaks_no_rule() {
    assert_eq!(check_board(&PINS), vec![]);
}

#[test]
fn pa0_is_not_tim1_ch1() {
    let pins = mutated(Signal::HighU, |u| {
        u.pin = Pin::new(b'A', 0);
    });
    let errors = check_board(&pins);
    assert!(
        errors.contains(&PinError::NoSuchTim1Signal {
            signal: Signal::HighU,
            pin: "PA0".into(),
            tim1: "CH1",
        }),
        "{errors:?}"
    );
    // PA0 also carries current U: the same pin twice.
    assert!(errors.iter().any(|e| matches!(
        e,
        PinError::DuplicatePin { pin, .. } if pin == "PA0"
    )));
}

#[test]
fn a_current_on_the_wrong_adc_fails() {
    // PC1 is ADC12_IN7: an input of ADC1 too, so only the sequence's rule catches it.
    let pins = mutated(Signal::CurrentV, |u| {
        u.function = Function::Analog {
            adc: Adc::Adc1,
            channel: 7,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::SlotOnWrongAdc {
            slot: 0,
            signal: Signal::CurrentV,
            expected: "ADC2",
        }]
    );
    // PA0 is ADC1's IN1, not IN5.
    let pins = mutated(Signal::CurrentU, |u| {
        u.function = Function::Analog {
            adc: Adc::Adc1,
            channel: 5,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::NotAnAdcInput {
            signal: Signal::CurrentU,
            pin: "PA0".into(),
            adc: "ADC1",
            channel: 5,
        }]
    );
}

#[test]
fn the_sensor_on_an_adc_that_cannot_convert_its_pin_fails() {
    // PB12 is ADC1_IN11 only: ADC2 has no input there.
    let pins = mutated(Signal::SensorX, |u| {
        u.function = Function::Analog {
            adc: Adc::Adc2,
            channel: 11,
        };
    });
    let errors = check_board(&pins);
    assert!(errors.contains(&PinError::NotAnAdcInput {
        signal: Signal::SensorX,
        pin: "PB12".into(),
        adc: "ADC2",
        channel: 11,
    }));
    assert!(errors.contains(&PinError::SlotOnWrongAdc {
        slot: 2,
        signal: Signal::SensorX,
        expected: "ADC1",
    }));
}

#[test]
fn a_duplicate_pin_fails() {
    // Sensor Y onto current W's pin PC0 (ADC12_IN6: a valid ADC2 input).
    let pins = mutated(Signal::SensorY, |u| {
        u.pin = Pin::new(b'C', 0);
        u.function = Function::Analog {
            adc: Adc::Adc2,
            channel: 6,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::DuplicatePin {
            pin: "PC0".into(),
            first: Signal::CurrentW,
            second: Signal::SensorY,
        }]
    );
}

#[test]
fn a_wrong_af_fails() {
    let pins = mutated(Signal::HighU, |u| {
        u.function = Function::Tim1 {
            signal: Tim1Signal::Ch1,
            af: 2,
            pull: Pull::None,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::WrongAf {
            signal: Signal::HighU,
            pin: "PA8".into(),
            tim1: "CH1",
            af: 2,
            st_af: vec![6],
        }]
    );
    // PA11 is TIM1_BKIN2 at AF12, never BKIN: the break on the shield's second link.
    let pins = mutated(Signal::OverCurrent, |u| u.pin = Pin::new(b'A', 11));
    let errors = check_board(&pins);
    assert!(errors.contains(&PinError::NoSuchTim1Signal {
        signal: Signal::OverCurrent,
        pin: "PA11".into(),
        tim1: "BKIN",
    }));
    assert!(errors
        .iter()
        .any(|e| matches!(e, PinError::ReservedPin { pin, .. } if pin == "PA11")));
}

#[test]
fn a_pin_outside_the_package_fails() {
    // PD8 exists on larger packages, not on the LQFP64.
    let pins = mutated(Signal::SensorX, |u| u.pin = Pin::new(b'D', 8));
    let errors = check_board(&pins);
    assert!(errors.contains(&PinError::NotInPackage {
        signal: Signal::SensorX,
        pin: "PD8".into(),
    }));
}

#[test]
fn a_sensor_on_a_pin_the_shield_drives_fails() {
    // PC4 is ADC2_IN5, but the shield's BEMF2 divider sits on it.
    let pins = mutated(Signal::SensorY, |u| {
        u.pin = Pin::new(b'C', 4);
        u.function = Function::Analog {
            adc: Adc::Adc2,
            channel: 5,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::ReservedPin {
            signal: Signal::SensorY,
            pin: "PC4".into(),
            user: "shield: BEMF2 divider R61",
        }]
    );
}

#[test]
fn one_channel_on_both_adcs_in_a_slot_fails() {
    // Slot 1 pairs current W (ADC1_IN6) with the bus voltage: put the latter on
    // ADC2's channel 6 too (PA1 is no IN6 either, which is caught as well).
    let mut pins = PINS.to_vec();
    pins.iter_mut()
        .find(|u| u.signal == Signal::BusVoltage)
        .unwrap()
        .function = Function::Analog {
        adc: Adc::Adc2,
        channel: 6,
    };
    let errors = check_board(&pins);
    assert!(
        errors.contains(&PinError::SameChannelInSlot {
            slot: 1,
            channel: 6
        }),
        "{errors:?}"
    );
}

#[test]
fn the_break_must_be_pulled_up() {
    let pins = mutated(Signal::OverCurrent, |u| {
        u.function = Function::Tim1 {
            signal: Tim1Signal::Bkin,
            af: 6,
            pull: Pull::None,
        };
    });
    assert_eq!(
        check_board(&pins),
        vec![PinError::BreakNotPulledUp { pin: "PA6".into() }]
    );
}

#[test]
fn a_missing_signal_fails() {
    let mut pins = PINS.to_vec();
    pins.retain(|u| u.signal != Signal::LowW);
    let errors = check_board(&pins);
    assert!(errors.contains(&PinError::SignalCount {
        signal: Signal::LowW,
        count: 0
    }));
}

#[test]
fn the_sequence_is_the_brief() {
    assert_eq!(
        INJECTED_SEQUENCE,
        [
            (Signal::CurrentU, Signal::CurrentV),
            (Signal::CurrentW, Signal::BusVoltage),
            (Signal::SensorX, Signal::SensorY),
        ]
    );
    // The sensor's channels are none of the currents'.
    let current_channels: Vec<u8> = [
        Signal::CurrentU,
        Signal::CurrentV,
        Signal::CurrentW,
        Signal::BusVoltage,
    ]
    .map(board_map::channel)
    .to_vec();
    for s in [Signal::SensorX, Signal::SensorY] {
        assert!(!current_channels.contains(&board_map::channel(s)));
    }
}

#[test]
fn current_scaling_arithmetic() {
    use board_map::current_sense::*;
    // 3.3 V / 4096 counts / (0.010 Ω · 5.18) = 15.55 mA per count, negative.
    assert!(
        (AMPS_PER_COUNT + 0.015_553).abs() < 1e-6,
        "{AMPS_PER_COUNT}"
    );
    assert_eq!(ZERO_COUNTS, 2048);
    // ±31.9 A before the ADC clips: three times the drive's I_MAX_A of 10 A.
    const { assert!(RANGE_A > 3.0 * 10.0) }
    let ratio = board_map::bus_voltage::RATIO;
    assert!((ratio - 19.152).abs() < 1e-3, "{ratio}");
}
