//! `hil-sim probe`'s parts that need no probe: the live decoder against whole-capture
//! decoding, the live status of a known capture, the ELF's load segments and RTT
//! block, and `write_recording` keeping the raw bytes whatever happens to the decoding.
//! (Recording through a session is tested end to end against the emulated chip.)
//!
//! The captures are hil-sim's commissioning power-ups encoded in the release `drive-fw`
//! ELF's own defmt format (as `rtt_log.rs` does); needs the release firmware (`cargo
//! xtask build-cross`).

use drive::commissioning::State;
use drive::telemetry::Line as Sent;
use hil_sim::probe_bench::{self, Ended, LiveStatus, Monitor, Recording};
use hil_sim::stream::{self, Decoded, Item, StreamDecoder};
use rand::{Rng, SeedableRng};
use std::fs;

mod capture;
use capture::{boots, capture, elf};

/// Both boots back to back with a few bytes corrupted: malformed frames are part of
/// what must decode the same however the bytes arrive.
fn damaged_capture() -> Vec<u8> {
    let (a, b) = boots();
    let mut bytes = capture(a);
    bytes.extend(capture(b));
    for k in [1000, 5000, 5001, 20_000] {
        if let Some(x) = bytes.get_mut(k) {
            *x ^= 0x5A;
        }
    }
    bytes
}

/// `bytes` fed in `chunks`, decoded frame by frame as they arrive.
fn decode_in_chunks<'a>(elf: &[u8], chunks: impl Iterator<Item = &'a [u8]>) -> Decoded {
    let table = stream::table(elf).unwrap();
    let mut dec = StreamDecoder::new(&table);
    let mut out = Decoded::default();
    for c in chunks {
        dec.received(c);
        while let Some(f) = dec.next_frame() {
            out.push(f);
        }
    }
    out
}

fn same(a: &Decoded, b: &Decoded) {
    assert_eq!(a.items, b.items);
    assert_eq!(a.malformed, b.malformed);
    assert_eq!(a.bad_lines, b.bad_lines);
}

#[test]
fn live_decoding_yields_what_decoding_the_whole_capture_does_however_it_is_chunked() {
    let elf = elf();
    let bytes = damaged_capture();
    let whole = stream::decode(&elf, &bytes).unwrap();
    assert!(whole.items.len() > 100, "{} items", whole.items.len());
    assert!(whole.malformed + whole.bad_lines.len() as u64 > 0);
    // Every byte boundary at once: one byte at a time.
    same(&decode_in_chunks(&elf, bytes.chunks(1)), &whole);
    // Random chunk sizes, up to RTT-buffer-sized reads.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for max in [3, 64, 1024, 4096] {
        let mut rest = &bytes[..];
        let mut chunks = Vec::new();
        while !rest.is_empty() {
            let n = rng.random_range(1..=max).min(rest.len());
            let (c, r) = rest.split_at(n);
            chunks.push(c);
            rest = r;
        }
        same(&decode_in_chunks(&elf, chunks.into_iter()), &whole);
    }
    // One split, at a spread of positions.
    for k in (0..bytes.len()).step_by(997) {
        let (a, b) = bytes.split_at(k);
        same(&decode_in_chunks(&elf, [a, b].into_iter()), &whole);
    }
}

#[test]
fn the_live_status_of_a_power_up_is_what_the_power_up_streamed() {
    let elf = elf();
    let table = stream::table(&elf).unwrap();
    let (first, second) = boots();
    for (boot, loaded) in [(first, false), (second, true)] {
        let bytes = capture(boot);
        let mut m = Monitor::new(&table);
        // In RTT-read-sized pieces, as `record` feeds it.
        for c in bytes.chunks(777) {
            m.feed(c);
        }
        let s: &LiveStatus = &m.status;
        let records: Vec<_> = (boot.streamed.iter())
            .filter_map(|l| match &l.line {
                Sent::Record(r) => Some(r),
                _ => None,
            })
            .collect();
        let events = (boot.streamed.iter())
            .filter(|l| matches!(l.line, Sent::Event(_)))
            .count();
        let last = records.last().unwrap();
        assert_eq!(s.records, records.len() as u64);
        assert_eq!(s.events, events as u64);
        assert_eq!(m.events.len(), events);
        assert_eq!(s.bytes, bytes.len() as u64);
        assert_eq!((s.malformed, s.bad_lines), (0, 0));
        assert_eq!(s.losses, stream::losses_of(&boot.streamed));
        assert_eq!(s.state, Some(boot.final_state));
        assert_eq!(s.state, Some(State::Run));
        assert_eq!(s.faults, last.faults);
        assert_eq!(s.omega_rad_s.to_bits(), last.omega_rad_s.to_bits());
        assert_eq!(
            s.residual_max_rad.to_bits(),
            last.residual_max_rad.to_bits()
        );
        let cycles = records.iter().map(|r| r.cycles_max).max().unwrap();
        assert_eq!(s.cycles_max, cycles);
        let whole = stream::decode(&elf, &bytes).unwrap();
        let mut t_last = whole.items.iter().filter_map(|i| match i {
            Item::Line(l) => l.t_ms(),
            Item::Other(_) => None,
        });
        assert_eq!(s.t_ms, t_last.next_back());
        assert_eq!(s.calibration_loaded, loaded);
        assert_eq!(boot.loaded_from_flash, loaded);
        // The state sequence: the simulated supervisor's transitions, in order.
        let seen: Vec<State> = m.states.iter().map(|c| c.state).collect();
        let went: Vec<State> = boot.transitions.iter().map(|(_, s)| *s).collect();
        assert!(
            went.ends_with(&seen) || seen == went,
            "{seen:?} vs {went:?}"
        );
        let run = m.states.iter().find(|c| c.state == State::Run).unwrap();
        assert_eq!(s.run_since_ms, Some(run.t_ms));
        assert_eq!(s.in_run_ms(), Some(s.t_ms.unwrap() - run.t_ms));
        assert!(s.line().starts_with("Run t="), "{}", s.line());
    }
}

#[test]
fn the_elfs_load_segments_and_rtt_block_are_found() {
    let elf = elf();
    let segs = probe_bench::load_segments(&elf).unwrap();
    // The vector table first in flash; everything by its load (flash) address.
    assert!(segs.iter().any(|s| s.paddr == 0x0800_0000), "{segs:?}");
    let flash = 0x0800_0000..0x0808_0000u64;
    let in_flash = segs.iter().filter(|s| flash.contains(&s.paddr)).count();
    assert!(in_flash >= 1);
    // The calibration pages (top of bank 2) are not the ELF's.
    for s in &segs {
        assert!(
            s.paddr + s.data.len() as u64 <= 0x0807_F000,
            "{:#x}",
            s.paddr
        );
    }
    let rtt = probe_bench::rtt_address(&elf).unwrap();
    assert!((0x2000_0000..0x2002_0000).contains(&rtt), "{rtt:#x}");
}

fn recording(raw: Vec<u8>, ended: Ended) -> Recording {
    Recording {
        raw,
        ended,
        status: LiveStatus::default(),
        states: Vec::new(),
        events: Vec::new(),
    }
}

#[test]
fn write_recording_keeps_the_raw_bytes_even_when_decoding_fails() {
    let dir = tempfile::tempdir().unwrap();
    let elf_path = stream::release_elf();
    let junk = b"\x01\x02 not a defmt stream \x00\x00".to_vec();
    let rec = recording(junk.clone(), Ended::ProbeLost("probe gone".into()));
    let e = probe_bench::write_recording(&rec, &elf_path, dir.path(), "lost").unwrap_err();
    let raw = dir.path().join("lost.defmt");
    assert_eq!(fs::read(&raw).unwrap(), junk);
    let msg = format!("{e:#}");
    assert!(msg.contains(&raw.display().to_string()), "{msg}");
    assert!(!dir.path().join("lost.csv").exists());
    // An ELF that cannot be read: the raw file is still written first.
    let missing = dir.path().join("no-such-elf");
    let e = probe_bench::write_recording(&rec, &missing, dir.path(), "noelf").unwrap_err();
    assert_eq!(fs::read(dir.path().join("noelf.defmt")).unwrap(), junk);
    assert!(format!("{e:#}").contains("noelf.defmt"), "{e:#}");
    // An empty capture (the probe lost before the first byte) is kept too.
    let empty = recording(Vec::new(), Ended::ProbeLost("gone".into()));
    assert!(probe_bench::write_recording(&empty, &elf_path, dir.path(), "empty").is_err());
    assert!(dir.path().join("empty.defmt").exists());
}

#[test]
fn write_recording_writes_what_rtt_log_writes() {
    let dir = tempfile::tempdir().unwrap();
    let (first, _) = boots();
    let rec = recording(capture(first), Ended::Stopped);
    probe_bench::write_recording(&rec, &stream::release_elf(), dir.path(), "power-up-1").unwrap();
    let p = |n: &str| dir.path().join(n);
    assert_eq!(fs::read(p("power-up-1.defmt")).unwrap(), rec.raw);
    let csv = fs::read_to_string(p("power-up-1.csv")).unwrap();
    assert!(csv.starts_with("t_s,seq,state"), "{}", &csv[..80]);
    let events = fs::read_to_string(p("power-up-1.events.csv")).unwrap();
    assert!(events.contains("state=Run"), "{events}");
    assert!(p("plots-power-up-1/speed.png").exists());
}

/// The emulated chip's own captures (`target/emu`, written by the emulator when it has
/// run; skipped otherwise): the real firmware's bytes, banner included, decode live as
/// they do whole, and the status ends in Run, the reboot with the calibration loaded.
#[test]
fn the_emulated_firmwares_captures_decode_live_as_whole() {
    let elf = elf();
    let table = stream::table(&elf).unwrap();
    for (name, loaded) in [("power-up-1", false), ("power-up-2", true)] {
        let path = hil_sim::checkout::target_dir().join(format!("emu/{name}.defmt"));
        let Ok(bytes) = fs::read(&path) else {
            eprintln!(
                "{}: absent (the emulator has not run): skipped",
                path.display()
            );
            continue;
        };
        let whole = stream::decode(&elf, &bytes).unwrap();
        same(&decode_in_chunks(&elf, bytes.chunks(1)), &whole);
        same(&decode_in_chunks(&elf, bytes.chunks(333)), &whole);
        if whole.malformed > 0 || !whole.bad_lines.is_empty() {
            // Captured from another build of the firmware than this checkout's.
            eprintln!(
                "{}: not this ELF's stream: status not checked",
                path.display()
            );
            continue;
        }
        let mut m = Monitor::new(&table);
        for c in bytes.chunks(512) {
            m.feed(c);
        }
        assert_eq!(m.status.state, Some(State::Run), "{name}");
        assert_eq!(m.status.calibration_loaded, loaded, "{name}");
        assert_eq!(m.status.losses, whole.losses(), "{name}");
        assert_eq!(m.status.losses.boots, 1, "{name}");
        assert!(m.status.other_lines >= 1, "{name}: the banner");
    }
}

/// The subcommand parses and, with a serial no probe has, fails before touching any
/// hardware with a message about the probe (none connected, or that serial not found).
#[test]
fn the_probe_subcommand_names_a_missing_probe() {
    let bin = env!("CARGO_BIN_EXE_hil-sim");
    let help = std::process::Command::new(bin)
        .args(["probe", "power-up", "--help"])
        .output()
        .unwrap();
    assert!(help.status.success());
    let help = String::from_utf8_lossy(&help.stdout);
    for flag in [
        "--elf",
        "--probe",
        "--chip",
        "--out",
        "--hold-s",
        "--timeout-s",
    ] {
        assert!(help.contains(flag), "{help}");
    }
    let out = std::process::Command::new(bin)
        .args(["probe", "flash", "--probe", "no-such-serial-0000"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no debug probe"), "{err}");
}

fn quiet() -> probe_bench::RecordOptions {
    probe_bench::RecordOptions {
        display: probe_bench::StatusDisplay::Off,
        poll_ms: 0,
        ..Default::default()
    }
}

/// A probe unplugged mid-run: the reads fail from some point on. The recording ends
/// `ProbeLost` with every byte read before, and a single failed read is retried.
#[test]
fn a_probe_lost_mid_run_keeps_the_capture_so_far() {
    let elf = elf();
    let table = stream::table(&elf).unwrap();
    let (first, _) = boots();
    let bytes = capture(first);
    let cut = bytes.len() / 2;
    let mut pos = 0;
    let mut calls = 0;
    let mut read = |buf: &mut [u8]| -> Result<usize, String> {
        calls += 1;
        if calls == 3 {
            return Err("transient SWD fault".into());
        }
        if pos >= cut {
            return Err("probe not found (USB disconnected)".into());
        }
        // Irregular pieces, some reads empty.
        let n = [0, 300, 1, 4096, 17][calls % 5]
            .min(cut - pos)
            .min(buf.len());
        buf[..n].copy_from_slice(&bytes[pos..pos + n]);
        pos += n;
        Ok(n)
    };
    let rec = probe_bench::record_from(&mut read, &table, &quiet(), &mut |_| false);
    assert_eq!(
        rec.ended,
        Ended::ProbeLost("probe not found (USB disconnected)".into())
    );
    assert_eq!(rec.raw, bytes[..cut]);
    assert_eq!(rec.status.bytes, cut as u64);
    assert!(rec.status.records > 0);
}

/// The caller's stop sees the live status: a power-up recording stops once Run has
/// lasted the hold, and the capture holds everything read until then.
#[test]
fn recording_stops_when_the_caller_says_so() {
    let elf = elf();
    let table = stream::table(&elf).unwrap();
    let (first, _) = boots();
    let bytes = capture(first);
    let mut pos = 0;
    let mut read = |buf: &mut [u8]| -> Result<usize, String> {
        // A capture that ends before the stop would otherwise be polled for ever.
        if pos == bytes.len() {
            return Err("capture exhausted before the stop".into());
        }
        let n = 200.min(bytes.len() - pos).min(buf.len());
        buf[..n].copy_from_slice(&bytes[pos..pos + n]);
        pos += n;
        Ok(n)
    };
    let mut stop = |s: &LiveStatus| s.in_run_ms().is_some_and(|t| t >= 100);
    let rec = probe_bench::record_from(&mut read, &table, &quiet(), &mut stop);
    assert_eq!(rec.ended, Ended::Stopped);
    assert!(rec.status.in_run_ms().unwrap() >= 100);
    assert!(rec.raw.len() < bytes.len(), "stopped before the end");
    assert_eq!(rec.raw, bytes[..rec.raw.len()]);
    assert_eq!(rec.states.last().unwrap().state, State::Run);
}
