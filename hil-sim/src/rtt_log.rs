//! `hil-sim rtt-log`: the firmware's captured RTT stream (`probe-rs run` output) to CSV,
//! a fault table and plots.
//!
//! The firmware prints three kinds of lines. Each is found by its marker anywhere in a
//! line, after ANSI colour codes are removed, so the timestamp, level and host prefixes
//! of any probe-rs or defmt-print format do not matter:
//!
//! ```text
//! mras-paths NAME[,NAME]...      path names, [A-Za-z0-9_+-]+, unique, commas (spaces allowed)
//! mras KEY=VALUE ...             t_ms state faults omega_rad_s amplitude converged revs
//!                                residual_max_rad cycles_max coef=[re, im, re, im, ...]
//! mras-fault KEY=VALUE ...       cause state t_ms
//! ```
//!
//! `mras-paths` names the coefficient columns of the `mras` lines after it, two numbers per
//! path in its order. Keys may come in any order; unknown keys are noted once and ignored;
//! a trailing ` (location)` after the message is ignored. Everything else (probe-rs
//! progress, defmt location lines, other log messages) is counted and ignored.
//!
//! A drive engineer resets boards mid-capture, so a capture is split into segments, one
//! CSV each: a new segment starts where the path list changes or time goes back.
//!
//! No silent data loss: a malformed line of ours is reported on stderr with file, line and
//! field and skipped; only the last one of the capture may be cut off (probe-rs killed)
//! without counting against the capture. The run fails, writing nothing, when no `mras`
//! line parses, a `mras` line comes before any `mras-paths`, a `mras-paths` line other than
//! the last is malformed (the columns after it would be unknown), or more than 1 % of the
//! `mras` lines are malformed. Outputs are written to temporary files and renamed into
//! place only when everything succeeded, as `replay` does.

use crate::pending::Pending;
use crate::plots::{self, Series};
use std::borrow::Cow;
use std::collections::HashSet;
use std::fmt::Write as _;
use std::fs::{self, File};
use std::io::{BufRead, BufReader, BufWriter};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    /// Captured `probe-rs run` output or saved log.
    #[arg(long)]
    pub input: PathBuf,
    /// CSV to write: t_s, state, faults, omega_rad_s, amplitude, converged, revs,
    /// residual_max_rad, cycles_max, then <path>_re, <path>_im per path. Later segments
    /// (firmware restarts) go to OUT.2.csv, OUT.3.csv, ...; faults to OUT.faults.csv.
    #[arg(long)]
    pub output: PathBuf,
    /// Directory for PNG/SVG plots (none if absent): coefficients and speed vs time,
    /// per segment (`coefficients.2.png`, ... for later segments).
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

/// Largest share of malformed `mras` lines (percent) a capture may have and still be
/// trusted: a few corrupt lines are noise, more mean a format mismatch.
const MALFORMED_LIMIT_PERCENT: u64 = 1;
/// Malformed lines shown on stderr; the rest are counted (a wrong format would otherwise
/// print the whole capture).
const MAX_REPORTED: u64 = 20;
/// Fault events printed in the summary table (all go to the faults CSV).
const MAX_FAULTS_PRINTED: usize = 20;

/// CSV columns before the coefficients.
const FIXED_COLUMNS: [&str; 13] = [
    "t_s",
    "state",
    "faults",
    "omega_rad_s",
    "amplitude",
    "converged",
    "revs",
    "residual_max_rad",
    "cycles_max",
    "cycles_mean",
    "cycles_min",
    "step_cycles_max",
    "step_cycles_mean",
];
/// Keys of a `mras` line that may be absent (older firmware): empty CSV field.
const OPTIONAL_DATA_KEYS: [&str; 4] = [
    "cycles_mean",
    "cycles_min",
    "step_cycles_max",
    "step_cycles_mean",
];
/// Keys of a `mras` line (all required).
const DATA_KEYS: [&str; 10] = [
    "t_ms",
    "state",
    "faults",
    "omega_rad_s",
    "amplitude",
    "converged",
    "revs",
    "residual_max_rad",
    "cycles_max",
    "coef",
];
/// Keys of a `mras-fault` line (all required).
const FAULT_KEYS: [&str; 3] = ["cause", "state", "t_ms"];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Paths,
    Data,
    Fault,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Paths => "mras-paths",
            Kind::Data => "mras",
            Kind::Fault => "mras-fault",
        }
    }
}

/// One parsed `mras` line (its coefficients live in [`Segment::coefs`]).
struct Row {
    t_ms: u64,
    state: String,
    faults: u8,
    omega_rad_s: f32,
    amplitude: f32,
    converged: bool,
    revs: u32,
    residual_max_rad: f32,
    cycles_max: u32,
    /// The optional keys, in `OPTIONAL_DATA_KEYS` order.
    optional: [Option<u32>; 4],
    line: u64,
}

/// Why a segment begins, for the summary.
enum SegmentStart {
    First,
    PathsChanged,
    TimeBack { from_ms: u64 },
}

/// Rows between two firmware restarts: one path list, non-decreasing time.
struct Segment {
    paths: Vec<String>,
    start: SegmentStart,
    rows: Vec<Row>,
    /// re, im per path, row after row (flat: one allocation instead of one per row).
    coefs: Vec<f32>,
    non_finite: u64,
}

impl Segment {
    fn width(&self) -> usize {
        2 * self.paths.len()
    }

    fn row_coefs(&self, k: usize) -> &[f32] {
        &self.coefs[k * self.width()..(k + 1) * self.width()]
    }
}

struct FaultEvent {
    t_ms: u64,
    cause: String,
    state: String,
    /// Segment the fault belongs to (1-based): times restart with every segment.
    segment: usize,
    line: u64,
}

/// The field that made a line malformed, and why.
struct FieldError {
    field: String,
    why: String,
}

fn bad(field: &str, why: impl Into<String>) -> FieldError {
    FieldError {
        field: field.into(),
        why: why.into(),
    }
}

/// A malformed line of ours whose fate waits for the next line of ours: the last one of
/// a capture is a cut-off warning, any other is an error.
struct Issue {
    kind: Kind,
    line: u64,
    msg: String,
}

/// Everything read from a capture.
struct Capture {
    name: String,
    lines: u64,
    segments: Vec<Segment>,
    faults: Vec<FaultEvent>,
    paths_lines: u64,
    ignored: u64,
    location_lines: u64,
    malformed_data: u64,
    malformed_faults: u64,
    /// Line of the cut-off last line of ours, if it was malformed.
    cut_off: Option<u64>,
}

impl Capture {
    fn rows(&self) -> usize {
        self.segments.iter().map(|s| s.rows.len()).sum()
    }
}

/// The line-by-line reader's state.
struct Parser {
    cap: Capture,
    /// Current path list and the line that set it.
    paths: Option<(Vec<String>, u64)>,
    /// A `mras-paths` line changed the list: the next row starts a segment.
    paths_changed: bool,
    pending: Option<Issue>,
    reported: u64,
    unknown_keys: HashSet<String>,
}

impl Parser {
    fn new(name: String) -> Self {
        Self {
            cap: Capture {
                name,
                lines: 0,
                segments: Vec::new(),
                faults: Vec::new(),
                paths_lines: 0,
                ignored: 0,
                location_lines: 0,
                malformed_data: 0,
                malformed_faults: 0,
                cut_off: None,
            },
            paths: None,
            paths_changed: false,
            pending: None,
            reported: 0,
            unknown_keys: HashSet::new(),
        }
    }

    fn line(&mut self, no: u64, raw: &str) -> Result<(), String> {
        self.cap.lines = no;
        let text = strip_ansi(raw);
        let Some((kind, rest)) = find_ours(&text) else {
            self.cap.ignored += 1;
            if text.trim_start().starts_with("└─") {
                self.cap.location_lines += 1;
            }
            return Ok(());
        };
        // A line of ours follows, so the pending malformed one was not the last.
        self.flush_pending()?;
        let rest = strip_location(rest);
        let parsed = match kind {
            Kind::Paths => {
                self.cap.paths_lines += 1;
                self.on_paths(rest, no)
            }
            Kind::Data => {
                if self.paths.is_none() {
                    return Err(format!(
                        "{}:{no}: `mras` line before any `mras-paths` line: its coefficient \
                         columns are unknown (capture started after the firmware's init? \
                         reset the board with the capture running)",
                        self.cap.name
                    ));
                }
                self.on_data(rest, no)
            }
            Kind::Fault => self.on_fault(rest, no),
        };
        if let Err(e) = parsed {
            self.pending = Some(Issue {
                kind,
                line: no,
                msg: format!(
                    "{}:{no}: `{}` line: field `{}`: {}",
                    self.cap.name,
                    kind.name(),
                    e.field,
                    e.why
                ),
            });
        }
        Ok(())
    }

    fn flush_pending(&mut self) -> Result<(), String> {
        let Some(issue) = self.pending.take() else {
            return Ok(());
        };
        match issue.kind {
            Kind::Paths => {
                return Err(format!(
                    "{}: the coefficient columns of the lines after it are unknown",
                    issue.msg
                ))
            }
            Kind::Data => self.cap.malformed_data += 1,
            Kind::Fault => self.cap.malformed_faults += 1,
        }
        self.reported += 1;
        if self.reported <= MAX_REPORTED {
            eprintln!("rtt-log: {}; line skipped", issue.msg);
        } else if self.reported == MAX_REPORTED + 1 {
            eprintln!("rtt-log: further malformed lines are skipped and counted, not shown");
        }
        Ok(())
    }

    fn note_unknown_keys(&mut self, kv: &[(&str, &str)], known: &[&str], kind: Kind, no: u64) {
        for (k, _) in kv {
            if !known.contains(k) && self.unknown_keys.insert(format!("{}:{k}", kind.name())) {
                eprintln!(
                    "rtt-log: note: {}:{no}: unknown key `{k}` in `{}` lines ignored (newer firmware?)",
                    self.cap.name,
                    kind.name()
                );
            }
        }
    }

    fn on_paths(&mut self, rest: &str, no: u64) -> Result<(), FieldError> {
        let names = parse_paths(rest)?;
        if self.paths.as_ref().is_some_and(|(p, _)| *p != names) {
            self.paths_changed = true;
        }
        // An identical list (re-printed, or a restart that time-back detects) keeps the segment.
        self.paths = Some((names, no));
        Ok(())
    }

    fn on_data(&mut self, rest: &str, no: u64) -> Result<(), FieldError> {
        let kv = key_values(rest)?;
        let known: Vec<&str> = DATA_KEYS
            .iter()
            .chain(&OPTIONAL_DATA_KEYS)
            .copied()
            .collect();
        self.note_unknown_keys(&kv, &known, Kind::Data, no);
        let optional = |key: &'static str| -> Result<Option<u32>, FieldError> {
            kv.iter()
                .find(|(k, _)| *k == key)
                .map(|(_, v)| parse_uint(v, key, u32::MAX.into()).map(|x| x as u32))
                .transpose()
        };
        let row = Row {
            t_ms: parse_uint(get(&kv, "t_ms")?, "t_ms", u64::MAX)?,
            state: parse_word(get(&kv, "state")?, "state")?,
            faults: parse_uint(get(&kv, "faults")?, "faults", u8::MAX.into())? as u8,
            omega_rad_s: parse_f32(get(&kv, "omega_rad_s")?, "omega_rad_s")?,
            amplitude: parse_f32(get(&kv, "amplitude")?, "amplitude")?,
            converged: parse_bool(get(&kv, "converged")?, "converged")?,
            revs: parse_uint(get(&kv, "revs")?, "revs", u32::MAX.into())? as u32,
            residual_max_rad: parse_f32(get(&kv, "residual_max_rad")?, "residual_max_rad")?,
            cycles_max: parse_uint(get(&kv, "cycles_max")?, "cycles_max", u32::MAX.into())? as u32,
            optional: [
                optional(OPTIONAL_DATA_KEYS[0])?,
                optional(OPTIONAL_DATA_KEYS[1])?,
                optional(OPTIONAL_DATA_KEYS[2])?,
                optional(OPTIONAL_DATA_KEYS[3])?,
            ],
            line: no,
        };
        let coefs = parse_coefs(get(&kv, "coef")?)?;
        let (paths, paths_line) = self.paths.as_ref().expect("checked by the caller");
        if coefs.len() != 2 * paths.len() {
            return Err(bad(
                "coef",
                format!(
                    "{} numbers, expected {} (re, im of {} from line {paths_line})",
                    coefs.len(),
                    2 * paths.len(),
                    paths.join(", ")
                ),
            ));
        }

        let last_t = self
            .cap
            .segments
            .last()
            .and_then(|s| s.rows.last())
            .map(|r| r.t_ms);
        let start = match last_t {
            None => Some(SegmentStart::First),
            Some(_) if self.paths_changed => Some(SegmentStart::PathsChanged),
            Some(t) if row.t_ms < t => Some(SegmentStart::TimeBack { from_ms: t }),
            Some(_) => None,
        };
        if let Some(start) = start {
            self.cap.segments.push(Segment {
                paths: paths.clone(),
                start,
                rows: Vec::new(),
                coefs: Vec::new(),
                non_finite: 0,
            });
            self.paths_changed = false;
        }
        let seg = self.cap.segments.last_mut().expect("pushed above");
        let floats = [row.omega_rad_s, row.amplitude, row.residual_max_rad];
        seg.non_finite += floats
            .iter()
            .chain(&coefs)
            .filter(|v| !v.is_finite())
            .count() as u64;
        seg.coefs.extend_from_slice(&coefs);
        seg.rows.push(row);
        Ok(())
    }

    fn on_fault(&mut self, rest: &str, no: u64) -> Result<(), FieldError> {
        let kv = key_values(rest)?;
        self.note_unknown_keys(&kv, &FAULT_KEYS, Kind::Fault, no);
        let cause = parse_word(get(&kv, "cause")?, "cause")?;
        let state = parse_word(get(&kv, "state")?, "state")?;
        let t_ms = parse_uint(get(&kv, "t_ms")?, "t_ms", u64::MAX)?;
        // A fault after a restart but before its first row belongs to the coming segment.
        let n = self.cap.segments.len();
        let segment = match self.cap.segments.last().and_then(|s| s.rows.last()) {
            Some(r) if self.paths_changed || t_ms < r.t_ms => n + 1,
            Some(_) => n,
            None => 1,
        };
        self.cap.faults.push(FaultEvent {
            t_ms,
            cause,
            state,
            segment,
            line: no,
        });
        Ok(())
    }

    fn finish(mut self) -> Result<Capture, String> {
        let name = self.cap.name.clone();
        if let Some(issue) = self.pending.take() {
            eprintln!(
                "rtt-log: warning: {}: the last line of the capture, cut off when it stopped? ignored",
                issue.msg
            );
            self.cap.cut_off = Some(issue.line);
        }
        let cap = self.cap;
        if cap.lines == 0 {
            return Err(format!(
                "{name}: empty file: expected the firmware's `mras-paths` and `mras t_ms=...` lines"
            ));
        }
        if cap.segments.is_empty() {
            return Err(format!(
                "{name}: no `mras t_ms=...` line parsed in {} lines ({} malformed `mras` lines, \
                 {} other lines): not a capture of the firmware's RTT stream?",
                cap.lines, cap.malformed_data, cap.ignored
            ));
        }
        let total = cap.rows() as u64 + cap.malformed_data;
        if cap.malformed_data * 100 > total * MALFORMED_LIMIT_PERCENT {
            return Err(format!(
                "{name}: {} of {total} `mras` lines malformed ({:.1} %, limit {MALFORMED_LIMIT_PERCENT} %): \
                 the capture or the line format is broken (see the lines reported above); nothing written",
                cap.malformed_data,
                cap.malformed_data as f64 * 100.0 / total as f64
            ));
        }
        Ok(cap)
    }
}

/// Removes ANSI escape sequences (probe-rs colours levels and timestamps on a terminal,
/// and `script` or `tee` keep them in the file).
fn strip_ansi(s: &str) -> Cow<'_, str> {
    if !s.contains('\x1b') {
        return Cow::Borrowed(s);
    }
    let mut out = String::with_capacity(s.len());
    let mut chars = s.chars();
    while let Some(c) = chars.next() {
        if c != '\x1b' {
            out.push(c);
            continue;
        }
        match chars.next() {
            // CSI: parameters up to a final byte in @..~ (colours are `ESC [ 32 m`).
            Some('[') => {
                for c in chars.by_ref() {
                    if ('@'..='~').contains(&c) {
                        break;
                    }
                }
            }
            // OSC (hyperlinks, titles): up to BEL or ESC \.
            Some(']') => {
                while let Some(c) = chars.next() {
                    if c == '\x07' {
                        break;
                    }
                    if c == '\x1b' {
                        chars.next();
                        break;
                    }
                }
            }
            // Two-character escapes: dropped with their second character.
            _ => {}
        }
    }
    Cow::Owned(out)
}

/// The kind of a line of ours and the text after its marker: `mras-paths` or `mras-fault`
/// followed by whitespace or the end, or `mras` followed by whitespace and `t_ms=`. The
/// marker must not continue a word (`nomras`, `drive_mras`).
fn find_ours(text: &str) -> Option<(Kind, &str)> {
    let mut from = 0;
    while let Some(off) = text[from..].find("mras") {
        let at = from + off;
        let after = &text[at + 4..];
        let starts_word = text[..at]
            .chars()
            .next_back()
            .is_none_or(|c| !(c.is_alphanumeric() || c == '_'));
        if starts_word {
            for (tag, kind) in [("-paths", Kind::Paths), ("-fault", Kind::Fault)] {
                if let Some(rest) = after.strip_prefix(tag) {
                    if rest.is_empty() || rest.starts_with(char::is_whitespace) {
                        return Some((kind, rest));
                    }
                }
            }
            if after.starts_with(char::is_whitespace) && after.trim_start().starts_with("t_ms=") {
                return Some((Kind::Data, after));
            }
        }
        from = at + 4;
    }
    None
}

/// Drops a trailing ` (location)` (defmt-print and custom probe-rs formats put the
/// location after the message): no value of ours contains `(`, so this is unambiguous.
fn strip_location(rest: &str) -> &str {
    let t = rest.trim_end();
    match t.rfind(" (") {
        Some(i) if t.ends_with(')') => &t[..i],
        _ => t,
    }
}

/// Splits `key=value key=value ...`; a value starting with `[` runs to the next `]` (so it
/// may hold spaces). Keys are lower-case words, each at most once.
fn key_values(rest: &str) -> Result<Vec<(&str, &str)>, FieldError> {
    let mut out: Vec<(&str, &str)> = Vec::new();
    let mut s = rest.trim_start();
    while !s.is_empty() {
        let token_end = s.find(char::is_whitespace).unwrap_or(s.len());
        let token = &s[..token_end];
        let Some(eq) = token.find('=') else {
            return Err(bad(&shorten(token), "not `key=value`"));
        };
        let key = &s[..eq];
        let key_ok = !key.is_empty()
            && key
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'_');
        if !key_ok {
            return Err(bad(&shorten(token), "not `key=value` (bad key)"));
        }
        let after = &s[eq + 1..];
        let (value, next) = if after.starts_with('[') {
            let Some(close) = after.find(']') else {
                return Err(bad(key, "no closing `]` (line cut off?)"));
            };
            (&after[..=close], &after[close + 1..])
        } else {
            let end = after.find(char::is_whitespace).unwrap_or(after.len());
            (&after[..end], &after[end..])
        };
        if value.is_empty() {
            return Err(bad(key, "empty"));
        }
        if !(next.is_empty() || next.starts_with(char::is_whitespace)) {
            return Err(bad(key, "text right after `]`"));
        }
        if out.iter().any(|(k, _)| *k == key) {
            return Err(bad(key, "appears twice"));
        }
        out.push((key, value));
        s = next.trim_start();
    }
    Ok(out)
}

/// A token for an error message, cut to a readable length.
fn shorten(s: &str) -> String {
    const MAX: usize = 40;
    match s.char_indices().nth(MAX) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s.to_string(),
    }
}

fn get<'a>(kv: &[(&str, &'a str)], key: &str) -> Result<&'a str, FieldError> {
    kv.iter()
        .find(|(k, _)| *k == key)
        .map(|(_, v)| *v)
        .ok_or_else(|| bad(key, "missing"))
}

/// An unsigned integer in decimal, `0x` hex or `0b` binary (how defmt prints bit sets
/// with `{=u8:#x}` / `{=u8:#b}`), at most `max`.
fn parse_uint(raw: &str, key: &str, max: u64) -> Result<u64, FieldError> {
    let (digits, radix) = if let Some(h) = raw.strip_prefix("0x") {
        (h, 16)
    } else if let Some(b) = raw.strip_prefix("0b") {
        (b, 2)
    } else {
        (raw, 10)
    };
    let ok = !digits.is_empty() && digits.chars().all(|c| c.is_digit(radix));
    let v = ok
        .then(|| u64::from_str_radix(digits, radix).ok())
        .flatten()
        .ok_or_else(|| bad(key, format!("not an unsigned integer: {raw:?}")))?;
    if v > max {
        return Err(bad(key, format!("{raw} is above {max}")));
    }
    Ok(v)
}

/// An f32 in decimal; `inf`, `-inf` and `NaN` are accepted (and written back as such),
/// a finite number beyond the f32 range is not (the firmware cannot have printed it).
fn parse_f32(raw: &str, key: &str) -> Result<f32, FieldError> {
    let v: f32 = raw
        .parse()
        .map_err(|_| bad(key, format!("not a number: {raw:?}")))?;
    let says_inf = raw
        .trim_start_matches(['+', '-'])
        .get(..3)
        .is_some_and(|p| p.eq_ignore_ascii_case("inf"));
    if v.is_infinite() && !says_inf {
        return Err(bad(key, format!("beyond the f32 range: {raw:?}")));
    }
    Ok(v)
}

fn parse_bool(raw: &str, key: &str) -> Result<bool, FieldError> {
    match raw {
        "true" => Ok(true),
        "false" => Ok(false),
        _ => Err(bad(key, format!("not `true` or `false`: {raw:?}"))),
    }
}

/// A state or cause name: letters, digits and `_` (a Rust enum variant's name).
fn parse_word(raw: &str, key: &str) -> Result<String, FieldError> {
    if raw.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        Ok(raw.to_string())
    } else {
        Err(bad(
            key,
            format!("not a word (letters, digits, _): {:?}", shorten(raw)),
        ))
    }
}

/// `[a, b, ...]` (defmt's array format) or `[]`.
fn parse_coefs(raw: &str) -> Result<Vec<f32>, FieldError> {
    let inner = raw
        .strip_prefix('[')
        .and_then(|r| r.strip_suffix(']'))
        .ok_or_else(|| bad("coef", format!("not `[n, n, ...]`: {:?}", shorten(raw))))?
        .trim();
    if inner.is_empty() {
        return Ok(Vec::new());
    }
    inner
        .split(',')
        .enumerate()
        .map(|(i, s)| {
            parse_f32(s.trim(), "coef")
                .map_err(|e| bad("coef", format!("number {}: {}", i + 1, e.why)))
        })
        .collect()
}

/// `NAME[,NAME]...`: the CSV column prefixes, so they are restricted to characters that
/// need no quoting and must be unique.
fn parse_paths(rest: &str) -> Result<Vec<String>, FieldError> {
    let rest = rest.trim();
    if rest.is_empty() {
        return Err(bad("paths", "empty list"));
    }
    let mut names: Vec<String> = Vec::new();
    for name in rest.split(',').map(str::trim) {
        let ok = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '+' | '-'));
        if !ok {
            return Err(bad(
                "paths",
                format!(
                    "bad path name {:?} (letters, digits, _, +, -; comma-separated)",
                    shorten(name)
                ),
            ));
        }
        if names.iter().any(|n| n == name) {
            return Err(bad("paths", format!("`{name}` appears twice")));
        }
        names.push(name.to_string());
    }
    Ok(names)
}

/// Reads the whole capture line by line (invalid UTF-8 is replaced, not fatal: a corrupt
/// byte in an unrelated line must not stop the run, and in a line of ours it fails a field).
fn read_capture(path: &Path) -> Result<Capture, String> {
    let name = path.display().to_string();
    let file = File::open(path).map_err(|e| format!("{name}: cannot open: {e}"))?;
    let mut rdr = BufReader::new(file);
    let mut parser = Parser::new(name.clone());
    let mut buf = Vec::new();
    let mut no = 0u64;
    loop {
        buf.clear();
        let n = rdr
            .read_until(b'\n', &mut buf)
            .map_err(|e| format!("{name}: cannot read after line {no}: {e}"))?;
        if n == 0 {
            break;
        }
        no += 1;
        let text = String::from_utf8_lossy(&buf);
        parser.line(no, text.trim_end_matches(['\n', '\r']))?;
    }
    parser.finish()
}

/// Plots rendered into a hidden directory inside DIR and moved into DIR on success, so a
/// failing run leaves no half set of plots; dropped uncommitted, the directory goes.
struct PendingPlots {
    tmp: PathBuf,
    dir: PathBuf,
    /// File names written (`coefficients.png`, ...).
    files: Vec<String>,
    committed: bool,
}

impl PendingPlots {
    fn create(dir: &Path) -> Result<Self, String> {
        fs::create_dir_all(dir)
            .map_err(|e| format!("{}: cannot create directory: {e}", dir.display()))?;
        let tmp = dir.join(format!(".rtt-log.{}.tmp", std::process::id()));
        fs::create_dir(&tmp)
            .map_err(|e| format!("{}: cannot create directory: {e}", tmp.display()))?;
        Ok(Self {
            tmp,
            dir: dir.to_path_buf(),
            files: Vec::new(),
            committed: false,
        })
    }

    fn chart(
        &mut self,
        stem: &str,
        title: &str,
        y_label: &str,
        series: &[Series],
    ) -> Result<(), String> {
        plots::line_chart(&self.tmp.join(stem), title, "time (s)", y_label, series)?;
        self.files.push(format!("{stem}.png"));
        self.files.push(format!("{stem}.svg"));
        Ok(())
    }

    fn commit(mut self) -> Result<(), String> {
        for f in &self.files {
            let dest = self.dir.join(f);
            fs::rename(self.tmp.join(f), &dest)
                .map_err(|e| format!("{}: cannot write: {e}", dest.display()))?;
        }
        self.committed = true;
        let _ = fs::remove_dir_all(&self.tmp);
        Ok(())
    }
}

impl Drop for PendingPlots {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
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

/// Suffix of segment `k`'s plot names: none, then `.2`, `.3`, ...
fn plot_suffix(k: usize) -> String {
    if k == 0 {
        String::new()
    } else {
        format!(".{}", k + 1)
    }
}

fn t_s(t_ms: u64) -> f64 {
    t_ms as f64 / 1000.0
}

/// Appends a value's `Display` form (shortest round trip; `NaN`, `inf`) as one CSV field.
fn put<W: std::io::Write>(
    w: &mut csv::Writer<W>,
    buf: &mut String,
    v: impl std::fmt::Display,
) -> csv::Result<()> {
    buf.clear();
    let _ = write!(buf, "{v}");
    w.write_field(buf.as_bytes())
}

/// Flushes and syncs a finished CSV writer (a rename must not publish unwritten data).
fn finish_csv(w: csv::Writer<BufWriter<File>>, name: &str) -> Result<(), String> {
    w.into_inner()
        .map_err(|e| format!("{name}: {}", e.error()))?
        .into_inner()
        .map_err(|e| format!("{name}: {}", e.error()))?
        .sync_all()
        .map_err(|e| format!("{name}: {e}"))
}

fn write_segment(seg: &Segment, dest: &Path) -> Result<Pending, String> {
    let (pending, file) = Pending::create(dest)?;
    let name = dest.display().to_string();
    let io = |e: csv::Error| format!("{name}: {e}");
    let mut w = csv::Writer::from_writer(BufWriter::new(file));
    let mut header: Vec<String> = FIXED_COLUMNS.iter().map(|c| c.to_string()).collect();
    for p in &seg.paths {
        header.push(format!("{p}_re"));
        header.push(format!("{p}_im"));
    }
    w.write_record(&header).map_err(io)?;
    let mut buf = String::new();
    for (k, r) in seg.rows.iter().enumerate() {
        put(&mut w, &mut buf, t_s(r.t_ms)).map_err(io)?;
        w.write_field(&r.state).map_err(io)?;
        put(&mut w, &mut buf, r.faults).map_err(io)?;
        put(&mut w, &mut buf, r.omega_rad_s).map_err(io)?;
        put(&mut w, &mut buf, r.amplitude).map_err(io)?;
        put(&mut w, &mut buf, r.converged).map_err(io)?;
        put(&mut w, &mut buf, r.revs).map_err(io)?;
        put(&mut w, &mut buf, r.residual_max_rad).map_err(io)?;
        put(&mut w, &mut buf, r.cycles_max).map_err(io)?;
        for c in r.optional {
            match c {
                Some(c) => put(&mut w, &mut buf, c).map_err(io)?,
                None => w.write_field("").map_err(io)?,
            }
        }
        for c in seg.row_coefs(k) {
            put(&mut w, &mut buf, c).map_err(io)?;
        }
        w.write_record(None::<&[u8]>).map_err(io)?;
    }
    finish_csv(w, &name)?;
    Ok(pending)
}

fn write_faults(faults: &[FaultEvent], dest: &Path) -> Result<Pending, String> {
    let (pending, file) = Pending::create(dest)?;
    let name = dest.display().to_string();
    let io = |e: csv::Error| format!("{name}: {e}");
    let mut w = csv::Writer::from_writer(BufWriter::new(file));
    w.write_record(["t_s", "cause", "state", "segment", "line"])
        .map_err(io)?;
    let mut buf = String::new();
    for f in faults {
        put(&mut w, &mut buf, t_s(f.t_ms)).map_err(io)?;
        w.write_field(&f.cause).map_err(io)?;
        w.write_field(&f.state).map_err(io)?;
        put(&mut w, &mut buf, f.segment).map_err(io)?;
        put(&mut w, &mut buf, f.line).map_err(io)?;
        w.write_record(None::<&[u8]>).map_err(io)?;
    }
    finish_csv(w, &name)?;
    Ok(pending)
}

/// Coefficient and speed charts of every segment. A chart without a single finite point
/// (an all-NaN speed) is skipped with a note rather than failing the conversion.
fn render_plots(cap: &Capture, plots: &mut PendingPlots) -> Vec<String> {
    let mut notes = Vec::new();
    let file = Path::new(&cap.name)
        .file_name()
        .map_or(cap.name.clone(), |f| f.to_string_lossy().into_owned());
    let many = cap.segments.len() > 1;
    for (k, seg) in cap.segments.iter().enumerate() {
        let sfx = plot_suffix(k);
        let title = |what: &str| {
            if many {
                format!("{what}, {file} segment {}", k + 1)
            } else {
                format!("{what}, {file}")
            }
        };
        let times: Vec<f64> = seg.rows.iter().map(|r| t_s(r.t_ms)).collect();
        let mut labels = Vec::new();
        let mut points = Vec::new();
        for (j, p) in seg.paths.iter().enumerate() {
            for (part, off) in [("re", 0), ("im", 1)] {
                labels.push(format!("{p} {part}"));
                points.push(
                    times
                        .iter()
                        .enumerate()
                        .map(|(i, &t)| (t, seg.row_coefs(i)[2 * j + off] as f64))
                        .collect::<Vec<_>>(),
                );
            }
        }
        let coef_series: Vec<Series> = labels
            .iter()
            .zip(&points)
            .map(|(l, p)| Series {
                label: l,
                points: p,
            })
            .collect();
        let speed: Vec<(f64, f64)> = times
            .iter()
            .zip(&seg.rows)
            .map(|(&t, r)| (t, r.omega_rad_s as f64))
            .collect();
        let speed_series = [Series {
            label: "ω̂ (omega_rad_s)",
            points: &speed,
        }];
        let charts = [
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
        ];
        for (stem, title, y_label, series) in charts {
            let finite = series
                .iter()
                .any(|s| s.points.iter().any(|p| p.0.is_finite() && p.1.is_finite()));
            let result = if finite {
                plots.chart(&stem, &title, y_label, series)
            } else {
                Err("no finite value".to_string())
            };
            if let Err(e) = result {
                notes.push(format!("{stem}: not drawn: {e}"));
            }
        }
    }
    notes
}

pub fn run(a: &Args) -> Result<(), String> {
    let cap = read_capture(&a.input)?;
    let seg_paths: Vec<PathBuf> = (0..cap.segments.len())
        .map(|k| segment_path(&a.output, k))
        .collect();
    let faults_path = tagged(&a.output, "faults");
    let input = fs::canonicalize(&a.input).ok();
    for p in seg_paths.iter().chain([&faults_path]) {
        if input.is_some() && fs::canonicalize(p).ok() == input {
            return Err(format!("{} would overwrite the input", p.display()));
        }
    }

    let mut pending = Vec::new();
    for (seg, path) in cap.segments.iter().zip(&seg_paths) {
        pending.push(write_segment(seg, path)?);
    }
    if !cap.faults.is_empty() {
        pending.push(write_faults(&cap.faults, &faults_path)?);
    }
    let mut plot_notes = Vec::new();
    let plots = match &a.plots {
        Some(dir) => {
            let mut p = PendingPlots::create(dir)?;
            plot_notes = render_plots(&cap, &mut p);
            Some(p)
        }
        None => None,
    };
    for p in pending {
        p.commit()?;
    }
    let plot_files = match plots {
        Some(p) => {
            let files: Vec<PathBuf> = p.files.iter().map(|f| p.dir.join(f)).collect();
            p.commit()?;
            files
        }
        None => Vec::new(),
    };
    print_summary(a, &cap, &seg_paths, &faults_path, &plot_files, &plot_notes);
    Ok(())
}

fn print_summary(
    a: &Args,
    cap: &Capture,
    seg_paths: &[PathBuf],
    faults_path: &Path,
    plot_files: &[PathBuf],
    plot_notes: &[String],
) {
    let data_lines = cap.rows() as u64 + cap.malformed_data;
    println!("hil-sim rtt-log: {}", cap.name);
    println!(
        "  {} lines: {data_lines} `mras`, {} `mras-paths`, {} `mras-fault`; {} others ignored \
         ({} of them location lines)",
        cap.lines,
        cap.paths_lines,
        cap.faults.len() as u64 + cap.malformed_faults,
        cap.ignored,
        cap.location_lines
    );
    if cap.malformed_data + cap.malformed_faults > 0 {
        println!(
            "  malformed, skipped (reported on stderr): {} `mras`, {} `mras-fault` lines",
            cap.malformed_data, cap.malformed_faults
        );
    }
    if let Some(line) = cap.cut_off {
        println!("  last line of ours (line {line}) cut off: ignored");
    }
    let segs = cap.segments.len();
    for (k, (seg, path)) in cap.segments.iter().zip(seg_paths).enumerate() {
        let (first, last) = (&seg.rows[0], seg.rows.last().expect("non-empty"));
        let why = match seg.start {
            SegmentStart::First => String::new(),
            SegmentStart::PathsChanged => ": the path list changed (firmware restarted)".into(),
            SegmentStart::TimeBack { from_ms } => format!(
                ": time went back from {} s to {} s (board reset)",
                t_s(from_ms),
                t_s(first.t_ms)
            ),
        };
        if segs > 1 {
            println!(
                "  segment {} of {segs}, from line {}{why} -> {}",
                k + 1,
                first.line,
                path.display()
            );
        } else {
            println!("  -> {}", path.display());
        }
        println!(
            "    {} rows, t = {} .. {} s, paths {}",
            seg.rows.len(),
            t_s(first.t_ms),
            t_s(last.t_ms),
            seg.paths.join(", ")
        );
        println!("    last state {}, revs {}", last.state, last.revs);
        match seg.rows.iter().find(|r| r.converged) {
            Some(c) => println!(
                "    converged at t = {} s (line {}); {} at the end",
                t_s(c.t_ms),
                c.line,
                if last.converged {
                    "still converged"
                } else {
                    "NOT converged"
                }
            ),
            None => println!("    not converged"),
        }
        let peak = seg
            .rows
            .iter()
            .max_by_key(|r| r.cycles_max)
            .expect("non-empty");
        println!(
            "    max cycles_max {} (t = {} s)",
            peak.cycles_max,
            t_s(peak.t_ms)
        );
        let bits = seg.rows.iter().fold(0u8, |b, r| b | r.faults);
        if bits != 0 {
            println!("    fault bits seen (OR of all rows): {bits:#010b}");
        }
        if seg.non_finite > 0 {
            println!(
                "    non-finite values: {} (written as NaN / inf)",
                seg.non_finite
            );
        }
        println!("    final coefficients (scaled units):");
        let last_coefs = seg.row_coefs(seg.rows.len() - 1);
        for (j, p) in seg.paths.iter().enumerate() {
            println!(
                "      {p:<22} {:+.6} {:+.6}j",
                last_coefs[2 * j],
                last_coefs[2 * j + 1]
            );
        }
    }
    if cap.faults.is_empty() {
        println!("  faults: none");
    } else {
        println!(
            "  faults: {} -> {}",
            cap.faults.len(),
            faults_path.display()
        );
        let wc = cap
            .faults
            .iter()
            .map(|f| f.cause.len())
            .max()
            .unwrap_or(0)
            .max(5);
        let ws = cap
            .faults
            .iter()
            .map(|f| f.state.len())
            .max()
            .unwrap_or(0)
            .max(5);
        println!(
            "    {:>10}  {:<wc$}  {:<ws$}  segment  line",
            "t_s", "cause", "state"
        );
        for f in cap.faults.iter().take(MAX_FAULTS_PRINTED) {
            println!(
                "    {:>10}  {:<wc$}  {:<ws$}  {:>7}  {}",
                t_s(f.t_ms),
                f.cause,
                f.state,
                f.segment,
                f.line
            );
        }
        if cap.faults.len() > MAX_FAULTS_PRINTED {
            println!(
                "    ... {} more in {}",
                cap.faults.len() - MAX_FAULTS_PRINTED,
                faults_path.display()
            );
        }
    }
    for n in plot_notes {
        println!("  note: {n}");
    }
    if let Some(dir) = &a.plots {
        println!("  plots: {} files in {}", plot_files.len(), dir.display());
    }
    // Files of an earlier run with more segments or with faults would pass for this one's.
    let next = segment_path(&a.output, segs);
    if next.exists() {
        println!(
            "  note: {} is from an earlier run: this capture has {segs} segment(s)",
            next.display()
        );
    }
    if cap.faults.is_empty() && faults_path.exists() {
        println!(
            "  note: {} is from an earlier run: this capture has no faults",
            faults_path.display()
        );
    }
    let mut wrote: Vec<String> = seg_paths.iter().map(|p| p.display().to_string()).collect();
    if !cap.faults.is_empty() {
        wrote.push(faults_path.display().to_string());
    }
    println!("  wrote {}", wrote.join(", "));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markers_are_found_in_any_format() {
        let data = "mras t_ms=1 state=A";
        for line in [
            "0.010000 INFO  mras t_ms=1 state=A",
            "[INFO ] mras t_ms=1 state=A (drive_fw src/main.rs:3)",
            "(HOST) 12:00:00.001 mras t_ms=1 state=A",
            "\x1b[2m0.01\x1b[0m \x1b[32mINFO \x1b[0mmras t_ms=1 state=A\x1b[0m",
            data,
        ] {
            let text = strip_ansi(line);
            let (kind, rest) = find_ours(&text).unwrap_or_else(|| panic!("{line:?}"));
            assert_eq!(kind, Kind::Data, "{line:?}");
            assert!(rest.trim_start().starts_with("t_ms=1 state=A"), "{line:?}");
        }
        for line in [
            "└─ drive_fw::mras::stream @ firmware/mras/src/lib.rs:1",
            "nomras t_ms=1",
            "mras state=A t_ms=1",
            "mras-pathsx a",
        ] {
            assert!(find_ours(line).is_none(), "{line:?}");
        }
        assert_eq!(find_ours("WARN mras-fault cause=X").unwrap().0, Kind::Fault);
        assert_eq!(find_ours("mras-paths a,b").unwrap().0, Kind::Paths);
    }

    #[test]
    fn trailing_location_is_dropped() {
        assert_eq!(strip_location(" a,b (drive_fw src/main.rs:3) "), " a,b");
        assert_eq!(strip_location(" t_ms=1 coef=[1, 2]"), " t_ms=1 coef=[1, 2]");
    }

    #[test]
    fn key_values_keep_bracketed_values_whole() {
        let kv = key_values(" t_ms=5 coef=[1.0, -2.5, NaN] x=y")
            .ok()
            .unwrap();
        assert_eq!(
            kv,
            [("t_ms", "5"), ("coef", "[1.0, -2.5, NaN]"), ("x", "y")]
        );
        assert_eq!(key_values("coef=[1.0, 2").err().unwrap().field, "coef");
        assert_eq!(key_values("a=1 a=2").err().unwrap().why, "appears twice");
        assert_eq!(key_values("a=1 junk").err().unwrap().field, "junk");
    }

    #[test]
    fn numbers() {
        assert!(parse_f32("inf", "k").ok().unwrap().is_infinite());
        assert!(parse_f32("NaN", "k").ok().unwrap().is_nan());
        assert!(parse_f32("1e40", "k").is_err());
        assert!(parse_f32("1.5x", "k").is_err());
        assert_eq!(parse_uint("0x05", "k", 255).ok(), Some(5));
        assert_eq!(parse_uint("0b101", "k", 255).ok(), Some(5));
        assert!(parse_uint("256", "k", 255).is_err());
        assert!(parse_uint("-1", "k", 255).is_err());
        assert!(parse_uint("+1", "k", 255).is_err());
        assert_eq!(parse_coefs("[]").ok().unwrap(), Vec::<f32>::new());
        assert_eq!(parse_coefs("[0.5,-1]").ok().unwrap(), vec![0.5, -1.0]);
        assert!(parse_coefs("[0.5,,1]").is_err());
    }

    #[test]
    fn paths_and_output_names() {
        assert_eq!(
            parse_paths(" offset, amplitude_quadrature,h-2 ")
                .ok()
                .unwrap(),
            ["offset", "amplitude_quadrature", "h-2"]
        );
        assert!(parse_paths("a,a").is_err());
        assert!(parse_paths("a b").is_err());
        assert!(parse_paths("").is_err());
        assert_eq!(
            segment_path(Path::new("d/out.csv"), 1),
            Path::new("d/out.2.csv")
        );
        assert_eq!(tagged(Path::new("out"), "faults"), Path::new("out.faults"));
    }
}
