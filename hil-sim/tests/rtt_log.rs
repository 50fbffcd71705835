//! `hil-sim rtt-log`: a captured RTT stream of the firmware becomes one CSV per firmware
//! run plus a fault table; bad lines are reported, not silently dropped, and a capture
//! that cannot be trusted writes nothing.
//!
//! `tests/data/rtt_capture.log` is probe-rs output of one run: flashing progress, defmt
//! location lines, an unrelated DEBUG line, ANSI colours on line 71, a `mras-fault` on
//! line 137, NaN residuals in the first two rows and a last line (251) cut off mid-`coef`.
//! `tests/data/rtt_reset.log` has a board reset: time goes back and the path list changes.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Runs `hil-sim rtt-log --input IN --output OUT [extra...]`: (success, stdout, stderr).
fn rtt_log(input: &Path, output: &Path, extra: &[&Path]) -> (bool, String, String) {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_hil-sim"));
    cmd.arg("rtt-log")
        .arg("--input")
        .arg(input)
        .arg("--output")
        .arg(output);
    if let Some(dir) = extra.first() {
        cmd.arg("--plots").arg(dir);
    }
    let out = cmd.output().expect("hil-sim runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Header and rows of a CSV, as strings.
fn read_csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let mut rdr = csv::Reader::from_path(path).unwrap_or_else(|e| panic!("{path:?}: {e}"));
    let header = rdr.headers().unwrap().iter().map(String::from).collect();
    let rows = rdr
        .records()
        .map(|r| r.unwrap().iter().map(String::from).collect())
        .collect();
    (header, rows)
}

/// File names in `dir`, sorted (also shows leftover temporary files).
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

/// The realistic capture with some lines (1-based) replaced.
fn corrupted_capture(dir: &Path, edits: &[(usize, &str, &str)]) -> PathBuf {
    let text = fs::read_to_string(data("rtt_capture.log")).unwrap();
    let mut lines: Vec<String> = text.split('\n').map(String::from).collect();
    for &(no, from, to) in edits {
        let line = &mut lines[no - 1];
        assert!(line.contains(from), "line {no}: {line}");
        *line = line.replacen(from, to, 1);
    }
    let path = dir.join("bad.log");
    fs::write(&path, lines.join("\n")).unwrap();
    path
}

const HEADER4: &str = "t_s,state,faults,omega_rad_s,amplitude,converged,revs,residual_max_rad,\
cycles_max,cycles_mean,cycles_min,step_cycles_max,step_cycles_mean,offset_re,offset_im,amplitude_quadrature_re,amplitude_quadrature_im,h4_re,h4_im,\
h5_re,h5_im";

#[test]
fn realistic_capture_gives_the_rows_the_values_and_the_fault_table() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run.csv");
    let (ok, stdout, stderr) = rtt_log(&data("rtt_capture.log"), &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");

    let (header, rows) = read_csv(&out);
    assert_eq!(header.join(","), HEADER4);
    // t_ms = 10 .. 1200 every 10 ms; 1210 is the cut-off last line.
    assert_eq!(rows.len(), 120);
    assert_eq!(
        rows[0].join(","),
        "0.01,Align,0,0,0.98065567,false,0,NaN,2179,,,,,0,0,0,0,0,0,0,0"
    );
    // Line 71 is ANSI-coloured.
    assert_eq!(
        rows[32][..9].join(","),
        "0.33,SpinUp,0,20.420351,0.9933426,false,0,0.0816,2185"
    );
    assert_eq!(
        rows[63].join(","),
        "0.64,Adapt,4,31.415926,0.9976312,false,1,0.016793998,2112,,,,,0.010635376,-0.0038909912,\
         0.026977539,0.007522583,-0.00440979,0.0019887288,0.0013834635,-0.00077819824"
    );
    assert_eq!(
        rows[119].join(","),
        "1.2,Tracking,0,31.415926,0.99963367,true,4,0.00079202955,2171,,,,,0.012284347,-0.004494273,\
         0.031160293,0.008688928,-0.00509351,0.002297073,0.0015979637,-0.00089885463"
    );
    for (k, r) in rows.iter().enumerate() {
        let t: f64 = r[0].parse().unwrap();
        assert!((t - 0.01 * (k + 1) as f64).abs() < 1e-9, "row {k}: {r:?}");
        assert_eq!(r.len(), header.len());
    }

    let (fh, faults) = read_csv(&dir.path().join("run.faults.csv"));
    assert_eq!(fh.join(","), "t_s,cause,state,segment,line");
    assert_eq!(faults, [["0.64", "SensorSaturated", "Adapt", "1", "137"]]);
    assert_eq!(names(dir.path()), ["run.csv", "run.faults.csv"]);

    assert!(stderr.contains("rtt_capture.log:251:"), "{stderr}");
    assert!(stderr.contains("cut off"), "{stderr}");
    for want in [
        "120 rows, t = 0.01 .. 1.2 s",
        "last state Tracking",
        "converged at t = 0.9 s (line 189); still converged at the end",
        "max cycles_max 2196 (t = 0.27 s)",
        "non-finite values: 2",
        "offset                 +0.012284 -0.004494j",
        "0.64  SensorSaturated  Adapt",
        "128 others ignored (124 of them location lines)",
        "line 251) cut off",
        "run.faults.csv",
    ] {
        assert!(stdout.contains(want), "no `{want}` in\n{stdout}");
    }
}

#[test]
fn board_reset_starts_a_second_csv() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.csv");
    let (ok, stdout, stderr) = rtt_log(&data("rtt_reset.log"), &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    assert_eq!(names(dir.path()), ["r.2.csv", "r.csv", "r.faults.csv"]);

    let (h1, r1) = read_csv(&out);
    assert_eq!(h1.join(","), HEADER4);
    let t1: Vec<&str> = r1.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(t1, ["0.01", "0.02", "0.03", "0.04", "0.05"]);

    let (h2, r2) = read_csv(&dir.path().join("r.2.csv"));
    assert_eq!(h2.len(), 13 + 6);
    assert_eq!(h2.last().unwrap(), "h4_im");
    let t2: Vec<&str> = r2.iter().map(|r| r[0].as_str()).collect();
    assert_eq!(t2, ["0.01", "0.02", "0.03", "0.04"]);

    // The fault came after the restart, before its first row.
    let (_, faults) = read_csv(&dir.path().join("r.faults.csv"));
    assert_eq!(faults, [["0.025", "SensorLost", "Align", "2", "19"]]);
    assert!(
        stdout.contains("segment 2 of 2, from line 21: the path list changed"),
        "{stdout}"
    );
    assert!(stdout.contains("r.2.csv"), "{stdout}");
}

#[test]
fn time_going_back_is_a_reset_even_with_the_same_paths() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("t.log");
    let row = |t: u32| {
        format!(
            "INFO  mras t_ms={t} state=Adapt faults=0 omega_rad_s=1.0 amplitude=1.0 \
             converged=false revs=0 residual_max_rad=0.1 cycles_max=2000 coef=[0.1, 0.2]\n"
        )
    };
    // A re-printed identical path list alone does not split; time going back does.
    let text = [
        "INFO  mras-paths offset\n".to_string(),
        row(10),
        row(20),
        "INFO  mras-paths offset\n".into(),
        row(20),
        row(30),
        row(10),
        row(20),
    ]
    .concat();
    fs::write(&log, text).unwrap();
    let out = dir.path().join("t.csv");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    assert_eq!(read_csv(&out).1.len(), 4);
    assert_eq!(read_csv(&dir.path().join("t.2.csv")).1.len(), 2);
    assert!(
        stdout.contains("from line 7: time went back from 0.03 s to 0.01 s"),
        "{stdout}"
    );
    assert!(stdout.contains("faults: none"), "{stdout}");
    assert_eq!(names(dir.path()), ["t.2.csv", "t.csv", "t.log"]);
}

#[test]
fn malformed_middle_line_is_reported_with_its_line_and_skipped() {
    let dir = tempfile::tempdir().unwrap();
    // Line 105 is t_ms=500: drop its `revs`. 1 of 120 lines is within the 1 % limit.
    let log = corrupted_capture(dir.path(), &[(105, " revs=0", "")]);
    let out = dir.path().join("out.csv");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("bad.log:105: `mras` line: field `revs`: missing; line skipped"),
        "{stderr}"
    );
    let (_, rows) = read_csv(&out);
    assert_eq!(rows.len(), 119);
    assert!(rows.iter().all(|r| r[0] != "0.5"));
    assert!(
        stdout.contains("malformed, skipped (reported on stderr): 1 `mras`"),
        "{stdout}"
    );
}

#[test]
fn more_than_one_percent_malformed_fails_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let log = corrupted_capture(
        dir.path(),
        &[
            (105, " revs=0", ""),
            (149, "omega_rad_s=31.415926", "omega_rad_s=31.4x"),
        ],
    );
    let out = dir.path().join("out.csv");
    fs::write(&out, "an earlier result\n").unwrap();
    let plots = dir.path().join("plots");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[&plots]);
    assert!(!ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("bad.log:149: `mras` line: field `omega_rad_s`: not a number"),
        "{stderr}"
    );
    assert!(
        stderr.contains("2 of 120 `mras` lines malformed (1.7 %, limit 1 %)"),
        "{stderr}"
    );
    assert_eq!(fs::read_to_string(&out).unwrap(), "an earlier result\n");
    assert_eq!(names(dir.path()), ["bad.log", "out.csv"]);
}

#[test]
fn malformed_fault_line_is_skipped_but_a_malformed_path_list_stops_the_run() {
    let dir = tempfile::tempdir().unwrap();
    // Line 137 is the fault: without its cause it is reported and skipped.
    let log = corrupted_capture(dir.path(), &[(137, "cause=SensorSaturated ", "")]);
    let out = dir.path().join("out.csv");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(
        stderr.contains("bad.log:137: `mras-fault` line: field `cause`: missing"),
        "{stderr}"
    );
    assert!(
        stdout.contains("0 `mras`, 1 `mras-fault` lines"),
        "{stdout}"
    );
    assert!(stdout.contains("faults: none"), "{stdout}");
    assert_eq!(read_csv(&out).1.len(), 120);

    // A bad path list: the columns of everything after it are unknown.
    let log = corrupted_capture(
        dir.path(),
        &[(5, "amplitude_quadrature,", "amplitude quadrature,")],
    );
    fs::remove_file(&out).unwrap();
    let (ok, _, stderr) = rtt_log(&log, &out, &[]);
    assert!(!ok);
    assert!(
        stderr.contains("bad.log:5: `mras-paths` line: field `paths`: bad path name"),
        "{stderr}"
    );
    assert_eq!(names(dir.path()), ["bad.log"]);
}

#[test]
fn empty_log_fails_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("empty.log");
    fs::write(&log, "").unwrap();
    let (ok, stdout, stderr) = rtt_log(&log, &dir.path().join("out.csv"), &[]);
    assert!(!ok, "{stdout}");
    assert!(
        stderr.contains(&format!("{}: empty file", log.display())),
        "{stderr}"
    );
    assert_eq!(names(dir.path()), ["empty.log"]);
}

#[test]
fn log_without_firmware_lines_or_paths_fails() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.csv");
    let other = dir.path().join("other.log");
    fs::write(&other, "Finished in 1.9s\nINFO booting\n").unwrap();
    let (ok, _, stderr) = rtt_log(&other, &out, &[]);
    assert!(!ok);
    assert!(
        stderr.contains("other.log: no `mras t_ms=...` line parsed in 2 lines"),
        "{stderr}"
    );

    let no_paths = dir.path().join("no_paths.log");
    fs::write(
        &no_paths,
        "INFO booting\nINFO mras t_ms=10 state=Adapt faults=0 omega_rad_s=1 amplitude=1 \
         converged=false revs=0 residual_max_rad=0 cycles_max=1 coef=[0, 0]\n",
    )
    .unwrap();
    let (ok, _, stderr) = rtt_log(&no_paths, &out, &[]);
    assert!(!ok);
    assert!(
        stderr.contains("no_paths.log:2: `mras` line before any `mras-paths` line"),
        "{stderr}"
    );
    assert_eq!(names(dir.path()), ["no_paths.log", "other.log"]);
}

#[test]
fn line_formats_of_probe_rs_and_defmt_print_are_all_accepted() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("formats.log");
    let tail = "state=Adapt omega_rad_s=-inf amplitude=1.0 converged=true revs=3 \
                residual_max_rad=0.5 cycles_max=2000 coef=[1.5,-2.5]";
    let text = [
        "[INFO ] mras-paths h-2 (drive_fw firmware/app/src/main.rs:120)\r\n".to_string(),
        format!("INFO  mras t_ms=10 faults=0x03 {tail}\r\n"),
        format!("(HOST) 2026-01-01 12:00:00.020 [INFO ] mras t_ms=20 faults=0b100 {tail}\n"),
        format!("\x1b[2m0.030000\x1b[0m \x1b[32mINFO \x1b[0mmras t_ms=30 faults=1 {tail}\x1b[0m\n"),
        format!("mras t_ms=40 faults=0 {tail}"),
    ]
    .concat();
    fs::write(&log, text).unwrap();
    let out = dir.path().join("f.csv");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    let (header, rows) = read_csv(&out);
    assert_eq!(
        &header[9..],
        [
            "cycles_mean",
            "cycles_min",
            "step_cycles_max",
            "step_cycles_mean",
            "h-2_re",
            "h-2_im"
        ]
    );
    let faults: Vec<&str> = rows.iter().map(|r| r[2].as_str()).collect();
    assert_eq!(faults, ["3", "4", "1", "0"]);
    assert_eq!(
        rows[3].join(","),
        "0.04,Adapt,0,-inf,1,true,3,0.5,2000,,,,,1.5,-2.5"
    );
    assert!(stdout.contains("non-finite values: 4"), "{stdout}");
    assert!(stderr.is_empty(), "{stderr}");
}

#[test]
fn plots_are_written_per_segment_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let plots = dir.path().join("plots");
    let (ok, stdout, stderr) =
        rtt_log(&data("rtt_reset.log"), &dir.path().join("r.csv"), &[&plots]);
    assert!(ok, "{stdout}\n{stderr}");
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
            "speed.svg",
        ]
    );
    for f in names(&plots) {
        assert!(fs::metadata(plots.join(&f)).unwrap().len() > 1000, "{f}");
    }
    assert!(stdout.contains("plots: 8 files in"), "{stdout}");
}

/// The firmware's own format strings (firmware/app/src/main.rs), filled with sample
/// values, parse without notes: stream and parser cannot drift apart unnoticed.
#[test]
fn the_firmware_stream_format_parses() {
    let src = include_str!("../../firmware/app/src/main.rs");
    let paths = src
        .lines()
        .find(|l| l.contains("const PATH_NAMES"))
        .and_then(|l| l.split('"').nth(1))
        .unwrap();
    // `coef` carries re, im of every configured path.
    let numbers = 2 * paths.split(',').count();
    let coef = (1..=numbers)
        .map(|i| format!("{:.1}", i as f32 / 10.0))
        .collect::<Vec<_>>()
        .join(", ");
    let start = src.find("\"mras t_ms=").expect("stream format in main.rs") + 1;
    let end = start + src[start..].find('"').unwrap();
    let line = src[start..end]
        .replace("{=u32}", "7")
        .replace("{=u8}", "0")
        .replace("{=f32}", "0.5")
        .replace("{=bool}", "true")
        .replace("{=str}", "Run")
        .replace("{=[?]}", &format!("[{coef}]"));
    assert!(!line.contains('{'), "unhandled placeholder in {line}");
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("fw.log");
    fs::write(&log, format!("INFO  mras-paths {paths}\nINFO  {line}\n")).unwrap();
    let out = dir.path().join("fw.csv");
    let (ok, stdout, stderr) = rtt_log(&log, &out, &[]);
    assert!(ok, "{stdout}\n{stderr}");
    assert!(!stderr.contains("unknown key"), "{stderr}");
    let (header, rows) = read_csv(&out);
    assert_eq!(rows.len(), 1);
    assert_eq!(header.len(), 13 + numbers);
}
