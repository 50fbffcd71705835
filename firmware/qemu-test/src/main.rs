//! The portable core on an emulated Cortex-M4F: runs the input vector embedded at build
//! time through `Tracker::step` and prints every step's outputs as f32 bit patterns over
//! semihosting (`mras_sim::write_trace_line`), for comparison with the host.
//!
//! Linked with the drive's own `memory.x` and built with the firmware's release profile.
//! Runs on QEMU's `netduinoplus2` (STM32F405: a Cortex-M4F with the same flash and SRAM
//! addresses as the STM32G474), see docs/performance.md.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use cortex_m_semihosting::debug;
#[cfg(not(cycles_mode))]
use cortex_m_semihosting::hio;
#[cfg(cycles_mode)]
use mras::{Adapter, Front, InjectionUpdate, PathKind};
use mras::{Config, Tracker};

static VECTOR: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/vector.bin"));

/// End the emulation with an exit code (semihosting), never return.
fn exit(code: debug::ExitStatus) -> ! {
    debug::exit(code);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    exit(debug::EXIT_FAILURE)
}

/// `core::fmt::Write` over the semihosting console.
#[cfg(not(cycles_mode))]
struct Console(hio::HostStream);

#[cfg(not(cycles_mode))]
impl core::fmt::Write for Console {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        self.0.write_all(s.as_bytes()).map_err(|_| core::fmt::Error)
    }
}

/// Steps run before the measured ones (spin-up and adaptation under way), and measured.
#[cfg(cycles_mode)]
const WARMUP_STEPS: usize = 4000;
#[cfg(cycles_mode)]
const MEASURED_STEPS: usize = 64;

/// Markers around each measured step: the instruction trace counts what runs between a
/// call to `mras_step_begin` and the next call to `mras_step_end`.
#[cfg(cycles_mode)]
#[inline(never)]
#[no_mangle]
pub extern "C" fn mras_step_begin(config: u32) {
    core::hint::black_box(config);
}

#[cfg(cycles_mode)]
#[inline(never)]
#[no_mangle]
pub extern "C" fn mras_step_end() {
    core::hint::black_box(());
}

#[cfg(cycles_mode)]
#[entry]
fn main() -> ! {
    // Prefixes of a full bank that starts as the core's default one (offset, C/D, h4, h5,
    // ...): observer only, + offset and C/D, + two harmonic paths (the configurations
    // docs/performance.md tabulates), the default bank, then all 16 paths (a path for
    // each error harmonic m = 1..16 of an N = 1 sensor, as a bank from the data can grow).
    // Per configuration: `MEASURED_STEPS` of the front (what runs in the control
    // interrupt), then as many of the adapter (the adaptation task), as the firmware
    // drives them.
    let default = Config::default();
    let mut full = [PathKind::Offset; mras::MAX_PATHS];
    let first = default.paths();
    let rest = (first.len() as i8 + 2..=15)
        .map(PathKind::Harmonic)
        .chain([-14, -15].map(PathKind::Harmonic));
    for (slot, kind) in full.iter_mut().zip(first.iter().copied().chain(rest)) {
        *slot = kind;
    }
    for (config, paths) in [0usize, 2, 4, first.len(), full.len()]
        .into_iter()
        .enumerate()
    {
        let mut cfg = Config::default();
        if cfg.set_paths(&full[..paths]).is_err() || cfg.validate().is_err() {
            exit(debug::EXIT_FAILURE);
        }
        let (Ok(mut front), Ok(mut adapter)) = (Front::new(cfg), Adapter::new(&cfg)) else {
            exit(debug::EXIT_FAILURE)
        };
        let mut pending = heapless::Deque::<InjectionUpdate, { mras::MAX_PATHS }>::new();
        let records = VECTOR.chunks_exact(mras_sim::VECTOR_RECORD_BYTES);
        for (k, rec) in records.take(WARMUP_STEPS + 2 * MEASURED_STEPS).enumerate() {
            let (x, y, tq) = mras_sim::decode_vector_record(rec);
            front.apply_due(&mut pending);
            let measure_front = (WARMUP_STEPS..WARMUP_STEPS + MEASURED_STEPS).contains(&k);
            let measure_adapter = k >= WARMUP_STEPS + MEASURED_STEPS;
            if measure_front {
                mras_step_begin(2 * config as u32);
            }
            let r = front.step(x, y, tq);
            let handoff = front.handoff().copied();
            if measure_front {
                mras_step_end();
            }
            core::hint::black_box(r.is_ok());
            if let Some(s) = handoff {
                if measure_adapter {
                    mras_step_begin(2 * config as u32 + 1);
                }
                let (_, update) = adapter.step(&s);
                if measure_adapter {
                    mras_step_end();
                }
                if let Some(u) = update {
                    if pending.push_back(u).is_err() {
                        exit(debug::EXIT_FAILURE);
                    }
                }
            } else if measure_adapter {
                // Every measured step must be a sample the adapter runs on.
                exit(debug::EXIT_FAILURE);
            }
        }
    }
    exit(debug::EXIT_SUCCESS)
}

#[cfg(not(cycles_mode))]
#[entry]
fn main() -> ! {
    let Ok(out) = hio::hstdout() else {
        exit(debug::EXIT_FAILURE)
    };
    let mut console = Console(out);
    let mut tracker = match Tracker::new(Config::default()) {
        Ok(t) => t,
        Err(_) => exit(debug::EXIT_FAILURE),
    };
    for (k, rec) in VECTOR
        .chunks_exact(mras_sim::VECTOR_RECORD_BYTES)
        .enumerate()
    {
        let (x, y, tq) = mras_sim::decode_vector_record(rec);
        let result = tracker.step(x, y, tq);
        if mras_sim::write_trace_line(&mut console, k, &result, &tracker).is_err() {
            exit(debug::EXIT_FAILURE);
        }
    }
    exit(debug::EXIT_SUCCESS)
}
