//! `hil-sim rtt-log`: the firmware's RTT stream to CSV, an event table and plots.
//!
//! The input is the raw defmt byte stream of RTT up channel 0 (docs/hardware.md says how
//! to capture it on a bench; `hil-sim` writes the same for its simulated power-ups),
//! decoded with `defmt-decoder` against the firmware ELF that produced it
//! ([`crate::stream`]). A `mras-paths` line names the coefficient columns of the
//! records after it. Every line of ours carries `seq`: frames RTT dropped (buffer full
//! or contended) show as gaps and are counted, whatever line was lost; records carry
//! `t_ms`, so records never written (the supervisor busy with flash) show as gaps in
//! time. The summary prints the losses: the drive's counters from the records
//! (hand-over, updates, events) and the frames lost ([`crate::stream::Losses`]).
//!
//! A drive engineer resets boards mid-capture, so a capture is split into segments, one
//! CSV each: a new segment starts where the path list changes or time goes back.
//!
//! No silent data loss: a frame that does not decode or a line of ours that does not fit
//! the schema is reported on stderr and counted; the run fails, writing nothing, when no
//! record decodes, a record comes before any `mras-paths` line, or more than 1 % of the
//! frames are bad. Outputs are written under temporary names and renamed into place only
//! when everything succeeded.

use crate::pending::{Pending, PendingDir};
use crate::plots::{self, Series};
use crate::stream::{self, Item, Line, Losses, Value};
use anyhow::{anyhow, bail, Context, Result};
use drive::telemetry::{FieldValue, Record, RECORD_KEYS};
use std::fmt::Write as _;
use std::fs;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Raw defmt bytes of RTT up channel 0 (not probe-rs's printed text).
    #[arg(long)]
    pub input: PathBuf,
    /// The firmware ELF that produced the stream (default: this checkout's release
    /// build, target/thumbv7em-none-eabihf/release/drive-fw).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// CSV to write: t_s, seq, state, faults, theta_rad, omega_rad_s, amplitude,
    /// converged, revs, residual_max_rad, cycles_max, cycles_mean, cycles_min,
    /// handoffs_dropped, updates_dropped, updates_late, events_dropped, then <path>_re,
    /// <path>_im per path. Later segments (firmware restarts) go to OUT.2.csv, OUT.3.csv,
    /// ...; the events (state changes, faults, flash) to OUT.events.csv.
    #[arg(long)]
    pub output: PathBuf,
    /// Directory for PNG/SVG plots (none if absent): coefficients and speed vs time,
    /// per segment (`coefficients.2.png`, ... for later segments).
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

/// Largest share of bad frames (percent) a capture may have and still be trusted.
const BAD_LIMIT_PERCENT: u64 = 1;
/// Bad lines shown on stderr; the rest are counted.
const MAX_REPORTED: usize = 20;
/// Events printed in the summary (all go to the events CSV).
const MAX_EVENTS_PRINTED: usize = 20;

/// Why a segment begins, for the summary.
enum SegmentStart {
    First,
    PathsChanged,
    TimeBack { from_ms: u32 },
}

/// Records between two firmware restarts: one path list, non-decreasing time.
struct Segment {
    paths: Vec<String>,
    start: SegmentStart,
    records: Vec<Record>,
    /// Each record's `seq` (None from a firmware before it).
    seqs: Vec<Option<u32>>,
}

struct EventRow {
    t_ms: u32,
    seq: Option<u32>,
    kind: String,
    details: String,
    /// Segment the event belongs to (1-based): times restart with every segment.
    segment: usize,
}

/// Everything read from a capture.
struct Capture {
    name: String,
    frames: u64,
    segments: Vec<Segment>,
    events: Vec<EventRow>,
    /// Other log lines (banner, HardFault report), in order.
    others: Vec<String>,
    malformed: u64,
    bad_lines: Vec<String>,
    /// Records missing between two received ones (gaps in t_ms).
    missing_records: u64,
    losses: Losses,
}

impl Capture {
    fn records(&self) -> usize {
        self.segments.iter().map(|s| s.records.len()).sum()
    }
}

fn elf_path(a: &Args) -> PathBuf {
    a.elf.clone().unwrap_or_else(stream::release_elf)
}

fn read_capture(a: &Args) -> Result<Capture> {
    let name = a.input.display().to_string();
    let bytes = fs::read(&a.input).with_context(|| format!("{name}: cannot read"))?;
    if bytes.is_empty() {
        bail!("{name}: empty: expected the firmware's raw defmt stream (RTT channel 0)");
    }
    let elf_path = elf_path(a);
    let elf = fs::read(&elf_path).with_context(|| {
        format!(
            "{}: cannot read the firmware ELF (build it: `cargo xtask build-cross`, or pass --elf)",
            elf_path.display()
        )
    })?;
    let decoded = stream::decode(&elf, &bytes).with_context(|| elf_path.display().to_string())?;
    let mut cap = Capture {
        name,
        frames: decoded.items.len() as u64 + decoded.malformed + decoded.bad_lines.len() as u64,
        segments: Vec::new(),
        events: Vec::new(),
        others: Vec::new(),
        malformed: decoded.malformed,
        losses: decoded.losses(),
        bad_lines: decoded.bad_lines,
        missing_records: 0,
    };
    let mut paths: Option<Vec<String>> = None;
    let mut paths_changed = false;
    for item in decoded.items {
        match item {
            Item::Other(text) => cap.others.push(text),
            Item::Line(l) if l.kind == "mras-paths" => {
                let names = l
                    .paths()
                    .with_context(|| format!("{}: `mras-paths`", cap.name))?;
                paths_changed |= paths.as_ref().is_some_and(|p| *p != names);
                paths = Some(names);
            }
            Item::Line(l) if l.kind == "mras" => match l.record() {
                Ok(r) => {
                    let Some(p) = &paths else {
                        bail!(
                            "{}: a record before any `mras-paths` line: its coefficient columns are \
                             unknown (capture started after the firmware's init? reset the board \
                             with the capture running)",
                            cap.name
                        );
                    };
                    let changed = std::mem::take(&mut paths_changed);
                    add_record(&mut cap, p, l.seq(), r, changed);
                }
                Err(e) => cap.bad_lines.push(format!("`mras` record: {e:#}")),
            },
            Item::Line(l) => add_event(&mut cap, &l, paths_changed),
        }
    }
    for b in cap.bad_lines.iter().take(MAX_REPORTED) {
        eprintln!("rtt-log: {}: {b}; skipped", cap.name);
    }
    if cap.bad_lines.len() > MAX_REPORTED {
        eprintln!(
            "rtt-log: {} more bad lines skipped",
            cap.bad_lines.len() - MAX_REPORTED
        );
    }
    if cap.segments.is_empty() {
        bail!(
            "{}: no record decoded in {} frames ({} malformed, {} bad lines of ours, {} other lines): \
             not this firmware's stream, or not the ELF that produced it?",
            cap.name,
            cap.frames,
            cap.malformed,
            cap.bad_lines.len(),
            cap.others.len()
        );
    }
    let bad = cap.malformed + cap.bad_lines.len() as u64;
    if bad * 100 > cap.frames * BAD_LIMIT_PERCENT {
        bail!(
            "{}: {bad} of {} frames bad (limit {BAD_LIMIT_PERCENT} %): the capture or the ELF does not \
             match; nothing written",
            cap.name,
            cap.frames
        );
    }
    Ok(cap)
}

fn add_record(
    cap: &mut Capture,
    paths: &[String],
    seq: Option<u32>,
    r: Record,
    paths_changed: bool,
) {
    let last = cap
        .segments
        .last()
        .and_then(|s| s.records.last())
        .map(|r| r.t_ms);
    let start = match last {
        None => Some(SegmentStart::First),
        Some(_) if paths_changed => Some(SegmentStart::PathsChanged),
        Some(t) if r.t_ms < t => Some(SegmentStart::TimeBack { from_ms: t }),
        Some(_) => None,
    };
    if let Some(start) = start {
        cap.segments.push(Segment {
            paths: paths.to_vec(),
            start,
            records: Vec::new(),
            seqs: Vec::new(),
        });
    }
    let seg = cap.segments.last_mut().expect("pushed above");
    if let [.., a, b] = seg.records.as_slice() {
        // The record period from the last two; a longer step lost records.
        let period = b.t_ms.saturating_sub(a.t_ms).max(1);
        let step = r.t_ms.saturating_sub(b.t_ms);
        if step > period + period / 2 {
            cap.missing_records += (step / period).saturating_sub(1) as u64;
        }
    }
    seg.records.push(r);
    seg.seqs.push(seq);
}

fn add_event(cap: &mut Capture, l: &Line, paths_changed: bool) {
    let t_ms = l.t_ms().unwrap_or(0);
    // An event after a restart but before its first record belongs to the coming segment.
    let n = cap.segments.len();
    let segment = match cap.segments.last().and_then(|s| s.records.last()) {
        Some(r) if paths_changed || t_ms < r.t_ms => n + 1,
        Some(_) => n,
        None => 1,
    };
    cap.events.push(EventRow {
        t_ms,
        seq: l.seq(),
        kind: l.kind.clone(),
        details: l.describe(),
        segment,
    });
}

/// `out.csv` → `out.<tag>.csv` (`out` → `out.<tag>`).
fn tagged(path: &Path, tag: &str) -> PathBuf {
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let name = match path.extension() {
        Some(ext) => format!("{stem}.{tag}.{}", ext.to_string_lossy()),
        None => format!("{stem}.{tag}"),
    };
    path.with_file_name(name)
}

/// Output of segment `k` (0-based): OUT.csv, then OUT.2.csv, OUT.3.csv, ...
fn segment_path(output: &Path, k: usize) -> PathBuf {
    if k == 0 {
        output.to_path_buf()
    } else {
        tagged(output, &(k + 1).to_string())
    }
}

fn t_s(t_ms: u32) -> f64 {
    t_ms as f64 / 1000.0
}

/// Write rows of fields (`Display` forms: shortest round trip, `NaN`, `inf`) to a CSV
/// that appears at `dest` on commit.
fn write_csv(
    dest: &Path,
    header: &[String],
    rows: impl Iterator<Item = Vec<String>>,
) -> Result<Pending> {
    let (pending, file) = Pending::create(dest)?;
    let name = dest.display().to_string();
    let mut w = csv::Writer::from_writer(BufWriter::new(file));
    w.write_record(header).with_context(|| name.clone())?;
    for r in rows {
        w.write_record(&r).with_context(|| name.clone())?;
    }
    // Flushed and synced: a rename must not publish unwritten data.
    let file = w
        .into_inner()
        .map_err(|e| anyhow!("{name}: {}", e.error()))?;
    file.into_inner()
        .map_err(|e| anyhow!("{name}: {}", e.error()))?
        .sync_all()
        .with_context(|| name.clone())?;
    Ok(pending)
}

fn write_segment(seg: &Segment, dest: &Path) -> Result<Pending> {
    // Time in seconds, the line's seq, the record's fields in stream order, then the
    // coefficients.
    let mut header: Vec<String> = ["t_s", "seq"]
        .into_iter()
        .chain(
            RECORD_KEYS
                .iter()
                .copied()
                .filter(|k| !matches!(*k, "t_ms" | "coef")),
        )
        .map(String::from)
        .collect();
    for p in &seg.paths {
        header.push(format!("{p}_re"));
        header.push(format!("{p}_im"));
    }
    let width = 2 * seg.paths.len();
    let rows = seg.records.iter().zip(&seg.seqs).map(move |(r, seq)| {
        let mut row: Vec<String> = r
            .fields()
            .filter(|(k, _)| *k != "coef")
            .map(|(k, v)| match (k, v) {
                ("t_ms", FieldValue::U32(t)) => t_s(t).to_string(),
                (_, v) => Value::from(v).text(),
            })
            .collect();
        row.insert(1, seq.map_or(String::new(), |s| s.to_string()));
        row.extend(r.coef.iter().take(width).map(|c| c.to_string()));
        row
    });
    write_csv(dest, &header, rows)
}

fn write_events(events: &[EventRow], dest: &Path) -> Result<Pending> {
    let header = ["t_s", "seq", "event", "details", "segment"].map(String::from);
    let rows = events.iter().map(|e| {
        vec![
            t_s(e.t_ms).to_string(),
            e.seq.map_or(String::new(), |s| s.to_string()),
            e.kind.clone(),
            e.details.clone(),
            e.segment.to_string(),
        ]
    });
    write_csv(dest, &header, rows)
}

/// Coefficient and speed charts of every segment, rendered into a hidden directory inside
/// the plot directory and moved into it on success (a failing run leaves no half set of
/// plots); a chart without a finite point is skipped with a note.
fn render_plots(cap: &Capture, plots: &mut PendingDir) -> Vec<String> {
    let mut notes = Vec::new();
    let file = Path::new(&cap.name)
        .file_name()
        .map_or(cap.name.clone(), |f| f.to_string_lossy().into_owned());
    let many = cap.segments.len() > 1;
    for (k, seg) in cap.segments.iter().enumerate() {
        let sfx = if k == 0 {
            String::new()
        } else {
            format!(".{}", k + 1)
        };
        let title = |what: &str| match many {
            true => format!("{what}, {file} segment {}", k + 1),
            false => format!("{what}, {file}"),
        };
        let over_time = |f: &dyn Fn(&Record) -> f32| -> Vec<(f64, f64)> {
            let at = |r: &Record| (t_s(r.t_ms), f64::from(f(r)));
            seg.records.iter().map(at).collect()
        };
        let coefs: Vec<(String, Vec<(f64, f64)>)> = seg
            .paths
            .iter()
            .flat_map(|p| [format!("{p} re"), format!("{p} im")])
            .enumerate()
            .map(|(j, label)| (label, over_time(&|r| r.coef[j])))
            .collect();
        let coef_series: Vec<Series> = coefs.iter().map(|(l, p)| Series::new(l, p)).collect();
        let speed = over_time(&|r| r.omega_rad_s);
        let speed_series = [Series::new("ω̂ (omega_rad_s)", &speed)];
        for (stem, title, y_label, series) in [
            (
                format!("coefficients{sfx}"),
                title("MRAS coefficients"),
                "coefficient (scaled units)",
                &coef_series[..],
            ),
            (
                format!("speed{sfx}"),
                title("estimated speed"),
                "ω̂ (rad/s)",
                &speed_series[..],
            ),
        ] {
            let finite = series
                .iter()
                .any(|s| s.points.iter().any(|p| p.0.is_finite() && p.1.is_finite()));
            let path = plots.tmp().join(&stem);
            let result = match finite {
                true => plots::line_chart(&path, &title, "time (s)", y_label, series),
                false => Err(anyhow!("no finite value")),
            };
            match result {
                Ok(()) => {
                    plots.add(format!("{stem}.png"));
                    plots.add(format!("{stem}.svg"));
                }
                Err(e) => notes.push(format!("{stem}: not drawn: {e:#}")),
            }
        }
    }
    notes
}

pub fn run(a: &Args) -> Result<()> {
    let cap = read_capture(a)?;
    let seg_paths: Vec<PathBuf> = (0..cap.segments.len())
        .map(|k| segment_path(&a.output, k))
        .collect();
    let events_path = tagged(&a.output, "events");
    let input = fs::canonicalize(&a.input).ok();
    for p in seg_paths.iter().chain([&events_path]) {
        if input.is_some() && fs::canonicalize(p).ok() == input {
            bail!("{} would overwrite the input", p.display());
        }
    }
    if let Some(dir) = a.output.parent().filter(|d| !d.as_os_str().is_empty()) {
        fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
    }
    let mut pending = Vec::new();
    for (seg, path) in cap.segments.iter().zip(&seg_paths) {
        pending.push(write_segment(seg, path)?);
    }
    if !cap.events.is_empty() {
        pending.push(write_events(&cap.events, &events_path)?);
    }
    let (plots, notes) = match &a.plots {
        Some(dir) => {
            let mut p = PendingDir::create(dir, "rtt-log")?;
            let notes = render_plots(&cap, &mut p);
            (Some(p), notes)
        }
        None => (None, Vec::new()),
    };
    for p in pending {
        p.commit()?;
    }
    let plot_files = match plots {
        Some(p) => p.commit()?,
        None => Vec::new(),
    };
    print!(
        "{}",
        summary(a, &cap, &seg_paths, &events_path, &plot_files, &notes)
    );
    Ok(())
}

fn summary(
    a: &Args,
    cap: &Capture,
    seg_paths: &[PathBuf],
    events_path: &Path,
    plot_files: &[PathBuf],
    notes: &[String],
) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "hil-sim rtt-log: {} (ELF {})",
        cap.name,
        elf_path(a).display()
    );
    let _ = writeln!(
        s,
        "  {} frames: {} records, {} events, {} other lines; {} malformed frames, {} bad lines",
        cap.frames,
        cap.records(),
        cap.events.len(),
        cap.others.len(),
        cap.malformed,
        cap.bad_lines.len()
    );
    let _ = writeln!(s, "  losses: {}", cap.losses.describe());
    if cap.missing_records > 0 {
        // With `seq` counted and no frame lost, the gap is records never written.
        let why = match (cap.losses.frames_lost, cap.losses.uncounted_lines) {
            (0, 0) => "no frame lost: the supervisor did not write them (a flash operation)",
            _ => "frames lost, or the supervisor was busy with flash",
        };
        let _ = writeln!(
            s,
            "  {} records missing (gaps in t_ms: {why})",
            cap.missing_records
        );
    }
    for o in cap.others.iter().take(5) {
        let _ = writeln!(s, "  firmware: {o}");
    }
    let segs = cap.segments.len();
    for (k, (seg, path)) in cap.segments.iter().zip(seg_paths).enumerate() {
        let (first, last) = (&seg.records[0], seg.records.last().expect("non-empty"));
        let why = match seg.start {
            SegmentStart::First => String::new(),
            SegmentStart::PathsChanged => ": the path list changed (firmware restarted)".into(),
            SegmentStart::TimeBack { from_ms } => format!(
                ": time went back from {} s to {} s (board reset)",
                t_s(from_ms),
                t_s(first.t_ms)
            ),
        };
        match segs > 1 {
            true => {
                let _ = writeln!(
                    s,
                    "  segment {} of {segs}{why} -> {}",
                    k + 1,
                    path.display()
                );
            }
            false => {
                let _ = writeln!(s, "  -> {}", path.display());
            }
        }
        let _ = writeln!(
            s,
            "    {} records, t = {} .. {} s, paths {}; last state {}, revs {}",
            seg.records.len(),
            t_s(first.t_ms),
            t_s(last.t_ms),
            seg.paths.join(", "),
            last.state.name(),
            last.revs
        );
        match seg.records.iter().find(|r| r.converged) {
            Some(c) => {
                let _ = writeln!(s, "    converged at t = {} s", t_s(c.t_ms));
            }
            None => {
                let _ = writeln!(s, "    not converged");
            }
        }
        let peak = seg.records.iter().map(|r| r.cycles_max).max().unwrap_or(0);
        let _ = writeln!(s, "    control interrupt: max {peak} cycles");
        let _ = writeln!(s, "    final coefficients (scaled units):");
        for (j, p) in seg.paths.iter().enumerate() {
            let _ = writeln!(
                s,
                "      {p:<22} {:+.6} {:+.6}j",
                last.coef[2 * j],
                last.coef[2 * j + 1]
            );
        }
    }
    if cap.events.is_empty() {
        let _ = writeln!(s, "  events: none");
    } else {
        let _ = writeln!(
            s,
            "  events: {} -> {}",
            cap.events.len(),
            events_path.display()
        );
        for e in cap.events.iter().take(MAX_EVENTS_PRINTED) {
            let _ = writeln!(
                s,
                "    {:>9.3} s  {:<22} {}{}",
                t_s(e.t_ms),
                e.kind,
                e.details,
                if segs > 1 {
                    format!("  (segment {})", e.segment)
                } else {
                    String::new()
                }
            );
        }
        if cap.events.len() > MAX_EVENTS_PRINTED {
            let _ = writeln!(s, "    ... {} more", cap.events.len() - MAX_EVENTS_PRINTED);
        }
    }
    for n in notes {
        let _ = writeln!(s, "  note: {n}");
    }
    if let Some(dir) = &a.plots {
        let _ = writeln!(
            s,
            "  plots: {} files in {}",
            plot_files.len(),
            dir.display()
        );
    }
    // Files of an earlier run with more segments or with events would pass for this one's.
    for stale in [segment_path(&a.output, segs), events_path.to_path_buf()] {
        let ours = stale == events_path && !cap.events.is_empty();
        if !ours && stale.exists() {
            let _ = writeln!(s, "  note: {} is from an earlier run", stale.display());
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_names() {
        assert_eq!(
            segment_path(Path::new("d/out.csv"), 1),
            Path::new("d/out.2.csv")
        );
        assert_eq!(
            segment_path(Path::new("d/out.csv"), 0),
            Path::new("d/out.csv")
        );
        assert_eq!(tagged(Path::new("out"), "events"), Path::new("out.events"));
    }
}
