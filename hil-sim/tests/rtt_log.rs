//! The firmware's RTT stream: hil-sim's commissioning power-ups encoded in the release
//! `drive-fw` ELF's own defmt format, decoded back with `defmt-decoder` against that ELF,
//! and turned by `hil-sim rtt-log` into CSV, an event table and plots; bad bytes are
//! reported, not silently dropped, and a capture that cannot be trusted writes nothing.
//!
//! Needs the release firmware (`cargo xtask build-cross`; `cargo xtask ci` builds it
//! before the host tests).

use drive::commissioning::State;
use drive::telemetry::{Line, Record};
use hil_sim::stream::{self, Formats, Item};
use std::fs;
use std::path::Path;
use std::process::Command;

mod capture;
use capture::{boots, capture, elf};

/// The release build's stream format carries every record and event bit for bit, each
/// line with its `seq`; the coefficients are live (they move through Adapt, are zero
/// before it and frozen in Verify), and the losses read from the decoded stream are
/// none, as the power-up streamed them.
#[test]
fn the_release_format_round_trips_and_the_coefficients_move_during_adapt() {
    let (first, _) = boots();
    let bytes = capture(first);
    let decoded = stream::decode(&elf(), &bytes).unwrap();
    assert_eq!(decoded.malformed, 0);
    assert!(decoded.bad_lines.is_empty(), "{:?}", decoded.bad_lines);
    let lines: Vec<_> = decoded
        .items
        .iter()
        .map(|i| match i {
            Item::Line(l) => l.clone(),
            Item::Other(o) => panic!("not ours: {o}"),
        })
        .collect();
    let names = lines[0].paths().unwrap();
    assert_eq!(names.len(), 7);
    assert_eq!(lines[0].seq(), Some(drive::telemetry::INIT_SEQ));
    let mut records = Vec::new();
    for (line, sent) in lines[1..].iter().zip(&first.streamed) {
        assert_eq!(line.seq(), Some(sent.seq));
        match &sent.line {
            Line::Record(r) => {
                let got = line.record().unwrap();
                let bits = |r: &Record| r.coef.map(f32::to_bits);
                assert_eq!(
                    (got.t_ms, got.state, bits(&got)),
                    (r.t_ms, r.state, bits(r))
                );
                assert_eq!(got.omega_rad_s.to_bits(), r.omega_rad_s.to_bits());
                assert_eq!(got.theta_rad.to_bits(), r.theta_rad.to_bits());
                assert_eq!(got, *r);
                records.push(got);
            }
            Line::Event(e) => {
                assert_eq!(line.kind, e.kind());
                assert_eq!(
                    line.t_ms(),
                    e.fields()
                        .iter()
                        .find(|f| f.0 == "t_ms")
                        .and_then(|f| match f.1 {
                            drive::telemetry::FieldValue::U32(t) => Some(t),
                            _ => None,
                        })
                );
            }
            Line::Paths(b) => {
                let names = drive::telemetry::bank_names(b.as_slice());
                assert_eq!(line.paths().unwrap().join(","), names.as_str());
            }
        }
    }
    assert_eq!(lines.len(), first.streamed.len() + 1);
    // Numbered from init's line on, one by one.
    assert!(lines
        .iter()
        .enumerate()
        .all(|(k, l)| l.seq() == Some(k as u32)));
    let losses = decoded.losses();
    assert!(losses.is_none(), "{losses:?}");
    assert_eq!(losses, first.losses());
    let in_state = |s: State| -> Vec<&Record> { records.iter().filter(|r| r.state == s).collect() };
    for r in in_state(State::SpinUp) {
        assert!(r.coef.iter().all(|c| *c == 0.0), "{r:?}");
    }
    let adapt = in_state(State::Adapt);
    assert!(adapt.len() >= 10, "{} records in Adapt", adapt.len());
    let moved = adapt.windows(2).filter(|w| w[0].coef != w[1].coef).count();
    assert!(
        moved >= adapt.len() - 2,
        "coefficients moved in {moved} of {} records",
        adapt.len()
    );
    let (a, b) = (adapt[0], adapt[adapt.len() - 1]);
    let change = a
        .coef
        .iter()
        .zip(&b.coef)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f32, f32::max);
    assert!(change > 0.05, "largest change over Adapt {change}");
    let verify = in_state(State::Verify);
    assert!(verify.windows(2).all(|w| w[0].coef == w[1].coef));
    // θ̂ in [0, 2π) (against the rotor: tests/telemetry.rs).
    let tau = std::f32::consts::TAU;
    assert!(records.iter().all(|r| (0.0..tau).contains(&r.theta_rad)));
}

/// Runs `hil-sim rtt-log --input IN --output OUT [--plots DIR]`: (success, stdout, stderr).
fn rtt_log(input: &Path, output: &Path, plots: Option<&Path>) -> (bool, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hil-sim"));
    cmd.arg("rtt-log")
        .arg("--input")
        .arg(input)
        .arg("--output")
        .arg(output);
    if let Some(dir) = plots {
        cmd.arg("--plots").arg(dir);
    }
    let out = cmd.output().expect("hil-sim runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut r = csv::Reader::from_path(path).unwrap();
    let header = r.headers().unwrap().iter().map(String::from).collect();
    let rows = r
        .records()
        .map(|x| x.unwrap().iter().map(String::from).collect())
        .collect();
    (header, rows)
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// Two power-ups back to back (a board reset: time goes back) become two CSVs; the
/// events table has the state changes and the flash events; plots per segment.
#[test]
fn a_capture_with_a_reset_gives_two_csvs_events_and_plots() {
    let (first, second) = boots();
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("capture.defmt");
    let mut bytes = capture(first);
    bytes.extend(capture(second));
    fs::write(&input, bytes).unwrap();
    let out = dir.path().join("out").join("run.csv");
    let plots = dir.path().join("plots");
    let (ok, stdout, stderr) = rtt_log(&input, &out, Some(&plots));
    assert!(ok, "{stdout}{stderr}");
    assert!(
        stdout.contains("segment 2 of 2: time went back"),
        "{stdout}"
    );
    let (header, rows) = read_csv(&out);
    assert_eq!(
        header[..17],
        [
            "t_s",
            "seq",
            "state",
            "faults",
            "theta_rad",
            "omega_rad_s",
            "amplitude",
            "converged",
            "revs",
            "residual_max_rad",
            "cycles_max",
            "cycles_mean",
            "cycles_min",
            "handoffs_dropped",
            "updates_dropped",
            "updates_late",
            "events_dropped"
        ]
    );
    assert_eq!(header.len(), 17 + 14);
    assert_eq!(header[17], "offset_re");
    // Each record's seq, from the first supervisor lines on.
    let seqs: Vec<u32> = rows.iter().map(|r| r[1].parse().unwrap()).collect();
    assert!(
        seqs.windows(2).all(|w| w[0] < w[1]) && seqs[0] >= 1,
        "{seqs:?}"
    );
    assert!(rows.iter().all(|r| r[13..17] == ["0", "0", "0", "0"]));
    assert!(rows.iter().any(|r| r[2] == "Adapt"));
    assert_eq!(rows.last().unwrap()[2], "Run");
    let (_, second_rows) = read_csv(&dir.path().join("out").join("run.2.csv"));
    assert!(second_rows.iter().all(|r| r[2] != "Adapt"));
    let (eh, events) = read_csv(&dir.path().join("out").join("run.events.csv"));
    assert_eq!(eh, ["t_s", "seq", "event", "details", "segment"]);
    assert!(events.iter().any(|e| e[2] == "mras-aligned" && e[4] == "1"));
    assert!(events.iter().any(|e| e[2] == "mras-stored"));
    assert!(events
        .iter()
        .any(|e| e[2] == "mras-loaded" && e[3] == "sequence=1" && e[4] == "2"));
    // Two boots in the capture (seq back to 0 at the second's init line), nothing lost.
    assert!(stdout.contains("losses: none"), "{stdout}");
    assert_eq!(
        names(&plots),
        [
            "coefficients.2.png",
            "coefficients.2.svg",
            "coefficients.png",
            "coefficients.svg",
            "speed.2.png",
            "speed.2.svg",
            "speed.png",
            "speed.svg"
        ]
    );
    // The store blocked the supervisor for the erase: its records are missing, and said.
    assert!(
        stdout.contains("records missing (gaps in t_ms: no frame lost"),
        "{stdout}"
    );
}

/// A damaged frame is counted and reported, the rest decodes; a capture cut off in the
/// middle of a frame loses only that frame.
#[test]
fn damaged_and_cut_off_captures_lose_only_the_damaged_frames() {
    let (first, _) = boots();
    let good = capture(first);
    let dir = tempfile::tempdir().unwrap();
    // A byte of a record in the middle set to the frame separator splits that frame.
    let mut damaged = good.clone();
    let mid = good.len() / 2;
    let at = mid + good[mid..].iter().position(|b| *b != 0).unwrap() + 3;
    damaged[at] = 0;
    // Cut in the middle of the last frame.
    damaged.truncate(damaged.len() - 5);
    let input = dir.path().join("damaged.defmt");
    fs::write(&input, &damaged).unwrap();
    let out = dir.path().join("d.csv");
    let (ok, stdout, stderr) = rtt_log(&input, &out, None);
    assert!(ok, "{stdout}{stderr}");
    let decoded = stream::decode(&elf(), &damaged).unwrap();
    let bad = decoded.malformed + decoded.bad_lines.len() as u64;
    assert!((1..=2).contains(&bad), "{bad}");
    assert!(stdout.contains(&format!("{} malformed frames", decoded.malformed)));
    // The damaged frame shows as a gap in seq: every line of ours before the last one
    // received is there or counted lost.
    let seqs: Vec<u32> = decoded
        .items
        .iter()
        .filter_map(|i| match i {
            Item::Line(l) => l.seq(),
            Item::Other(_) => None,
        })
        .collect();
    let lost = decoded.losses().frames_lost;
    assert!(lost >= 1, "{lost}");
    assert_eq!(lost, (*seqs.last().unwrap() as u64 + 1) - seqs.len() as u64);
    assert!(stdout.contains(&format!("{lost} frames lost")), "{stdout}");
    let (_, rows) = read_csv(&out);
    let sent = first
        .streamed
        .iter()
        .filter(|s| matches!(s.line, Line::Record(_)))
        .count();
    assert!(
        rows.len() >= sent - 3 && rows.len() < sent,
        "{} of {sent}",
        rows.len()
    );
}

#[test]
fn too_many_bad_frames_fail_and_write_nothing() {
    let (first, _) = boots();
    let mut bytes = capture(first);
    // Every 40th byte after the path list zeroed: most records break.
    for k in (200..bytes.len()).step_by(40) {
        bytes[k] = 0;
    }
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("bad.defmt");
    fs::write(&input, &bytes).unwrap();
    let (ok, stdout, stderr) = rtt_log(&input, &dir.path().join("x.csv"), None);
    assert!(!ok, "{stdout}");
    assert!(stderr.contains("nothing written"), "{stderr}");
    assert_eq!(names(dir.path()), ["bad.defmt"]);
}

#[test]
fn records_before_the_path_list_and_foreign_inputs_fail_clearly() {
    let (first, _) = boots();
    let full = capture(first);
    let formats = Formats::from_elf(&elf()).unwrap();
    let mut paths_only = Vec::new();
    formats
        .encode_paths(
            drive::telemetry::INIT_SEQ,
            "offset,amplitude_quadrature,h4,h5,h6,h7,h8",
            &mut paths_only,
        )
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let no_paths = dir.path().join("no-paths.defmt");
    fs::write(&no_paths, &full[paths_only.len()..]).unwrap();
    let (ok, _, stderr) = rtt_log(&no_paths, &dir.path().join("a.csv"), None);
    assert!(!ok);
    assert!(stderr.contains("before any `mras-paths`"), "{stderr}");

    let text = dir.path().join("printed.log");
    fs::write(&text, "INFO  mras t_ms=1 state=Run\n").unwrap();
    let (ok, _, stderr) = rtt_log(&text, &dir.path().join("b.csv"), None);
    assert!(!ok);
    assert!(stderr.contains("no record decoded"), "{stderr}");

    let empty = dir.path().join("empty.defmt");
    fs::write(&empty, b"").unwrap();
    let (ok, _, stderr) = rtt_log(&empty, &dir.path().join("c.csv"), None);
    assert!(!ok);
    assert!(stderr.contains("empty"), "{stderr}");
}

/// The schema check: a stream format whose names disagree with `drive::telemetry` is
/// refused by name (the encoder checks the ELF's parameter names against the fields').
#[test]
fn the_elf_format_names_match_the_schema() {
    let formats = Formats::from_elf(&elf()).unwrap();
    let mut out = Vec::new();
    let wrong = [("t_ms", stream::Value::Uint(1))];
    let e = formats.encode("mras", wrong, &mut out).unwrap_err();
    assert!(format!("{e:#}").contains("parameters"), "{e:#}");
    let renamed = [
        ("seq", stream::Value::Uint(1)),
        ("state", stream::Value::Str("Run".into())),
        ("time", stream::Value::Uint(1)),
    ];
    let e = formats.encode("mras-state", renamed, &mut out).unwrap_err();
    assert!(format!("{e:#}").contains("`t_ms`"), "{e:#}");
}
