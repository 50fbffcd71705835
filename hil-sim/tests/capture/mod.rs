//! What the stream tests share: hil-sim's commissioning power-ups encoded in the
//! release `drive-fw` ELF's own defmt format, as the firmware would have sent them.

use calib_record::RamFlash;
use hil_sim::power_up::{self, Boot};
use hil_sim::rig::SimFlash;
use hil_sim::scenario::Scenario;
use hil_sim::stream::{self, Formats};
use std::fs;
use std::sync::OnceLock;

/// The release ELF (`cargo xtask build-cross`; `cargo xtask ci` builds it before the
/// host tests).
pub fn elf() -> Vec<u8> {
    let p = stream::release_elf();
    fs::read(&p).unwrap_or_else(|e| {
        panic!(
            "{}: {e}: build the release firmware first (`cargo xtask build-cross`)",
            p.display()
        )
    })
}

/// The scenario's two power-ups (erased flash, then the stored calibration).
pub fn boots() -> &'static (Boot, Boot) {
    static BOOTS: OnceLock<(Boot, Boot)> = OnceLock::new();
    BOOTS.get_or_init(|| {
        let sc = Scenario::load("commissioning").unwrap();
        let (a, flash) =
            power_up::boot(&sc, SimFlash::new(RamFlash::default()), 1, 3.6, None).unwrap();
        let (b, _) = power_up::boot(&sc, flash, 2, 1.0, None).unwrap();
        (a, b)
    })
}

/// Boot `b`'s stream as the release ELF encodes it.
pub fn capture(b: &Boot) -> Vec<u8> {
    let sc = Scenario::load("commissioning").unwrap();
    let names = drive::telemetry::path_names(&sc.core_config(None).unwrap());
    let formats = Formats::from_elf(&elf()).unwrap();
    stream::encode_streamed(&formats, &names, &b.streamed).unwrap()
}
