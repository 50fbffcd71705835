//! The firmware's RTT stream, decoded with `defmt-decoder` against the ELF that produced
//! it, and encoded in that ELF's format for hil-sim's own streams.
//!
//! The schema has one owner, `drive::telemetry`: its log functions are the format
//! strings, `Record::fields` and `Event::fields` the same fields in the same order. A line
//! is decoded by the format string's own structure: each parameter's type comes from the
//! format string in the ELF, its name from the `name=` before it (a `,` continues the
//! previous name: `coef=` is a list), its value from the decoder's rendering of that one
//! parameter (exact: f32 prints shortest-round-trip). Nothing is matched by pattern over
//! printed text.
//!
//! Every line of ours carries `seq`, its number since boot (`drive::telemetry`'s doc):
//! [`Decoded::losses`] counts the frames lost from its gaps, beside the drive's own loss
//! counters from the records. Captures of a firmware from before `seq`, θ̂ and the loss
//! counters still decode: θ̂ reads as NaN, the counters as 0, and [`Losses`] says how
//! many lines it could not count losses in.

use crate::rig::Streamed;
use anyhow::{anyhow, bail, Context, Result};
use defmt_decoder::{DecodeError, Table};
use defmt_parser::{Fragment, ParserMode, Type};
use drive::commissioning::State;
use drive::telemetry::{FieldValue, Line as StreamLine, Record, INIT_SEQ, RECORD_KEYS, SEQ_KEY};
use mras::MAX_PATHS;
use serde_json::Value as Json;
use std::path::PathBuf;

/// A decoded value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    Uint(u64),
    F32(f32),
    Bool(bool),
    Str(String),
}

impl Value {
    fn parse(ty: &Type, text: &str) -> Result<Self> {
        fn num<T: std::str::FromStr>(text: &str, what: &str) -> Result<T>
        where
            T::Err: std::error::Error + Send + Sync + 'static,
        {
            text.parse()
                .with_context(|| format!("`{text}` is not {what}"))
        }
        Ok(match ty {
            Type::U8 | Type::U16 | Type::U32 | Type::U64 | Type::Usize => {
                Value::Uint(num(text, "an integer")?)
            }
            Type::F32 => Value::F32(num(text, "an f32")?),
            Type::Bool => Value::Bool(num(text, "a bool")?),
            Type::Str | Type::IStr => Value::Str(text.to_string()),
            other => bail!("parameter type {other:?} is not part of the stream schema"),
        })
    }

    /// The value as text: `Display` of the value (shortest round trip for f32).
    pub fn text(&self) -> String {
        match self {
            Value::Uint(v) => v.to_string(),
            Value::F32(v) => v.to_string(),
            Value::Bool(v) => v.to_string(),
            Value::Str(v) => v.clone(),
        }
    }
}

impl From<FieldValue> for Value {
    fn from(v: FieldValue) -> Self {
        match v {
            FieldValue::U32(x) => Value::Uint(x.into()),
            FieldValue::U16(x) => Value::Uint(x.into()),
            FieldValue::U8(x) => Value::Uint(x.into()),
            FieldValue::F32(x) => Value::F32(x),
            FieldValue::Bool(x) => Value::Bool(x),
            FieldValue::Str(x) => Value::Str(x.to_string()),
        }
    }
}

/// One decoded line of ours: its marker (`mras`, `mras-state`, ...) and named fields
/// (an unnamed field, as in `mras-paths`, has the empty name).
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    pub kind: String,
    pub fields: Vec<(String, Value)>,
}

impl Line {
    /// The first field named `key` (the emulator's scenarios read states this way).
    pub fn get(&self, key: &str) -> Option<&Value> {
        self.fields.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    /// The `t_ms` of the line, if it has one.
    pub fn t_ms(&self) -> Option<u32> {
        match self.get("t_ms")? {
            Value::Uint(v) => u32::try_from(*v).ok(),
            _ => None,
        }
    }

    /// The line's number since boot (None from a firmware before `seq`).
    pub fn seq(&self) -> Option<u32> {
        match self.get(SEQ_KEY)? {
            Value::Uint(v) => u32::try_from(*v).ok(),
            _ => None,
        }
    }

    /// `key=value` pairs as text, for event tables (without `t_ms` and `seq`).
    pub fn describe(&self) -> String {
        self.fields
            .iter()
            .filter(|(k, _)| k != "t_ms" && k != SEQ_KEY)
            .map(|(k, v)| format!("{k}={}", v.text()))
            .collect::<Vec<_>>()
            .join(" ")
    }

    /// The values of the fields named `key`, in order.
    fn values(&self, key: &str) -> Vec<&Value> {
        let named = self.fields.iter().filter(|(k, _)| k == key);
        named.map(|(_, v)| v).collect()
    }

    /// A record line as the typed record.
    pub fn record(&self) -> Result<Record> {
        if self.kind != "mras" {
            bail!("a `{}` line is not a record", self.kind);
        }
        for (k, _) in &self.fields {
            if !RECORD_KEYS.contains(&k.as_str()) && k != SEQ_KEY {
                bail!("unknown field `{k}`");
            }
        }
        let one = |key: &str| -> Result<&Value> {
            match self.values(key)[..] {
                [v] => Ok(v),
                [] => bail!("no `{key}`"),
                _ => bail!("`{key}` appears twice"),
            }
        };
        let f32_of = |key: &str, v: &Value| match v {
            Value::F32(x) => Ok(*x),
            other => bail!("`{key}`: {other:?} is not an f32"),
        };
        let uint = |key: &str, max: u32| match one(key)? {
            Value::Uint(v) if *v <= u64::from(max) => Ok(*v as u32),
            other => bail!("`{key}`: {other:?} is not an integer up to {max}"),
        };
        let state_name = match one("state")? {
            Value::Str(s) => s,
            other => bail!("`state`: {other:?} is not a name"),
        };
        let coefs: Vec<f32> = self
            .values("coef")
            .into_iter()
            .map(|v| f32_of("coef", v))
            .collect::<Result<_>>()?;
        // A stream of the earlier 8-path firmware carries 16 values: the paths it has.
        let n = 2 * MAX_PATHS;
        if coefs.len() > n || !coefs.len().is_multiple_of(2) {
            bail!(
                "`coef`: {} values, the schema has {n} (re and im of each path)",
                coefs.len()
            );
        }
        let mut coef = [0.0; 2 * MAX_PATHS];
        coef[..coefs.len()].copy_from_slice(&coefs);
        let f32_at = |key: &str| f32_of(key, one(key)?);
        // Fields a firmware from before the loss counters and θ̂ does not send.
        let newer = self.has_loss_counters();
        let counter = |key: &str| if newer { uint(key, u32::MAX) } else { Ok(0) };
        Ok(Record {
            t_ms: uint("t_ms", u32::MAX)?,
            state: State::from_name(state_name)
                .ok_or_else(|| anyhow!("`state`: unknown state `{state_name}`"))?,
            faults: uint("faults", u8::MAX.into())? as u8,
            theta_rad: if newer {
                f32_at("theta_rad")?
            } else {
                f32::NAN
            },
            omega_rad_s: f32_at("omega_rad_s")?,
            amplitude: f32_at("amplitude")?,
            converged: match one("converged")? {
                Value::Bool(b) => *b,
                other => bail!("`converged`: {other:?} is not a bool"),
            },
            revs: uint("revs", u32::MAX)?,
            residual_max_rad: f32_at("residual_max_rad")?,
            cycles_max: uint("cycles_max", u32::MAX)?,
            cycles_mean: uint("cycles_mean", u32::MAX)?,
            cycles_min: uint("cycles_min", u32::MAX)?,
            handoffs_dropped: counter("handoffs_dropped")?,
            updates_dropped: counter("updates_dropped")?,
            updates_late: counter("updates_late")?,
            events_dropped: counter("events_dropped")?,
            coef,
        })
    }

    /// Whether a record line carries the loss counters (a firmware from before them
    /// does not).
    pub fn has_loss_counters(&self) -> bool {
        self.get("handoffs_dropped").is_some()
    }

    /// The path names of a `mras-paths` line (`paths=`, or the one unnamed field of a
    /// firmware from before `seq`).
    pub fn paths(&self) -> Result<Vec<String>> {
        let names = match self.fields.as_slice() {
            [(_, Value::Str(s))] => Some(s),
            _ => match self.get("paths") {
                Some(Value::Str(s)) => Some(s),
                _ => None,
            },
        };
        match (self.kind.as_str(), names) {
            ("mras-paths", Some(s)) => {
                let names: Vec<String> = s.split(',').map(|n| n.trim().to_string()).collect();
                if names.iter().any(|n| n.is_empty()) {
                    bail!("empty path name in `{s}`");
                }
                Ok(names)
            }
            _ => bail!("not a `mras-paths` line"),
        }
    }
}

/// Whether a line's marker (its first word) is one of ours: `mras` or `mras-...`.
fn is_ours(marker: &str) -> bool {
    marker == "mras" || marker.starts_with("mras-")
}

/// Each parameter's name and type, in order.
type Params = Vec<(String, Type)>;

/// The marker of a format of ours and each parameter's name and type: a literal's
/// trailing `name=` names the parameters after it (a `,` continues the name, for lists);
/// None for a format that is not ours.
fn schema(frags: &[Fragment<'_>]) -> Result<Option<(String, Params)>> {
    let Some(Fragment::Literal(first)) = frags.first() else {
        return Ok(None);
    };
    let kind = first.split_whitespace().next().unwrap_or("");
    if !is_ours(kind) {
        return Ok(None);
    }
    let mut key = String::new();
    let mut params = Vec::new();
    for (n, frag) in frags.iter().enumerate() {
        match frag {
            Fragment::Literal(lit) => {
                let lit: &str = lit;
                let rest = if n == 0 { &lit[kind.len()..] } else { lit }.trim();
                if let Some(name) = rest.strip_suffix('=') {
                    key = name.rsplit(char::is_whitespace).next().unwrap_or("").into();
                } else if !rest.is_empty() && rest != "," {
                    bail!("`{kind}`: unexpected text `{rest}` between fields");
                }
            }
            Fragment::Parameter(p) => params.push((key.clone(), p.ty.clone())),
        }
    }
    Ok(Some((kind.to_string(), params)))
}

/// A line of ours from a frame's fragments and each parameter's rendered text.
fn line_of(
    frags: &[Fragment<'_>],
    mut texts: impl Iterator<Item = String>,
) -> Result<Option<Line>> {
    let Some((kind, params)) = schema(frags)? else {
        return Ok(None);
    };
    let mut fields = Vec::with_capacity(params.len());
    for (key, ty) in params {
        let text = texts
            .next()
            .ok_or_else(|| anyhow!("`{kind}` `{key}`: no value"))?;
        let v = Value::parse(&ty, &text).with_context(|| format!("`{kind}` `{key}`"))?;
        fields.push((key, v));
    }
    Ok(Some(Line { kind, fields }))
}

/// A decoded frame: one of ours, or any other log line (as the decoder prints it).
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    Line(Line),
    Other(String),
}

/// What a byte stream held.
#[derive(Debug, Default)]
pub struct Decoded {
    pub items: Vec<Item>,
    /// Frames the decoder could not decode (corrupt or truncated bytes).
    pub malformed: u64,
    /// Lines of ours whose fields did not fit the schema, with the reason.
    pub bad_lines: Vec<String>,
}

/// Whether a line not of ours is the firmware's banner, written first at every boot.
pub fn is_banner(text: &str) -> bool {
    text.starts_with("drive-fw:")
}

/// What a stream lost. The drive's counters are cumulative since boot: per boot, those
/// of its last record received, summed over the boots.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Losses {
    /// Samples the adaptation task never got (its queue was full).
    pub handoffs_dropped: u64,
    /// Updates the adaptation's queue could not take when they were made.
    pub updates_dropped: u64,
    /// Updates applied after the period they were due in.
    pub updates_late: u64,
    /// Events a supervisor step could not hold (never a fault).
    pub events_dropped: u64,
    /// Lines of ours that never arrived (records, events, `mras-paths`): gaps in `seq`,
    /// and a boot's lines before its first one received. Lines before the first of a
    /// capture that starts mid-boot are not counted.
    pub frames_lost: u64,
    /// Boots seen (a banner, or `seq` not increasing).
    pub boots: u32,
    /// Lines of ours without `seq` and records without the counters (a firmware from
    /// before them): their losses are unknown, not zero.
    pub uncounted_lines: u64,
}

impl Losses {
    /// Two captures' losses together (e.g. the boots of one scenario, each its own
    /// capture).
    pub fn plus(&self, o: &Losses) -> Losses {
        Losses {
            handoffs_dropped: self.handoffs_dropped + o.handoffs_dropped,
            updates_dropped: self.updates_dropped + o.updates_dropped,
            updates_late: self.updates_late + o.updates_late,
            events_dropped: self.events_dropped + o.events_dropped,
            frames_lost: self.frames_lost + o.frames_lost,
            boots: self.boots + o.boots,
            uncounted_lines: self.uncounted_lines + o.uncounted_lines,
        }
    }

    /// Nothing lost, and every line counted.
    pub fn is_none(&self) -> bool {
        self.handoffs_dropped == 0
            && self.updates_dropped == 0
            && self.updates_late == 0
            && self.events_dropped == 0
            && self.frames_lost == 0
            && self.uncounted_lines == 0
    }

    /// One line: `none`, or each loss that is not zero.
    pub fn describe(&self) -> String {
        if self.is_none() {
            return "none".into();
        }
        let parts = [
            (
                self.handoffs_dropped,
                "samples not handed to the adaptation",
            ),
            (self.updates_dropped, "updates dropped"),
            (self.updates_late, "updates late"),
            (self.events_dropped, "events dropped"),
            (self.frames_lost, "frames lost (gaps in seq)"),
            (
                self.uncounted_lines,
                "lines without seq or counters (not counted)",
            ),
        ];
        let named: Vec<String> = parts
            .iter()
            .filter(|(n, _)| *n > 0)
            .map(|(n, what)| format!("{n} {what}"))
            .collect();
        named.join(", ")
    }
}

/// Counts [`Losses`] over a stream's lines in order.
#[derive(Clone, Debug, Default)]
pub struct LossCounter {
    losses: Losses,
    /// The `seq` the next line should have (None: unknown, at the start of a capture).
    expect: Option<u32>,
    /// The current boot's counters from its last record.
    counters: [u64; 4],
    in_boot: bool,
}

impl LossCounter {
    /// The banner: a new boot, whose first line of ours is `seq` = INIT_SEQ.
    pub fn banner(&mut self) {
        self.new_boot();
        self.expect = Some(INIT_SEQ);
    }

    /// A line of ours: its `seq`, and for a record, its counters (None when the record
    /// has none).
    pub fn line(&mut self, seq: Option<u32>, record: Option<Option<&Record>>) {
        if !self.in_boot {
            self.new_boot();
        }
        match seq {
            None => self.losses.uncounted_lines += 1,
            Some(s) => {
                match self.expect {
                    // `seq` went back with no banner: a new boot whose banner was lost;
                    // its lines before this one too.
                    Some(e) if s < e => {
                        self.new_boot();
                        self.losses.frames_lost += u64::from(s - INIT_SEQ);
                    }
                    Some(e) => self.losses.frames_lost += u64::from(s - e),
                    None => {}
                }
                self.expect = Some(s.wrapping_add(1));
            }
        }
        match record {
            Some(Some(r)) => {
                self.counters = [
                    r.handoffs_dropped,
                    r.updates_dropped,
                    r.updates_late,
                    r.events_dropped,
                ]
                .map(u64::from)
            }
            Some(None) => self.losses.uncounted_lines += u64::from(seq.is_some()),
            None => {}
        }
    }

    fn new_boot(&mut self) {
        self.close_boot();
        self.in_boot = true;
        self.losses.boots += 1;
    }

    fn close_boot(&mut self) {
        let [h, u, l, e] = std::mem::take(&mut self.counters);
        self.losses.handoffs_dropped += h;
        self.losses.updates_dropped += u;
        self.losses.updates_late += l;
        self.losses.events_dropped += e;
    }

    pub fn finish(mut self) -> Losses {
        self.close_boot();
        self.losses
    }

    /// The losses so far, the counting going on (a live capture's status).
    pub fn so_far(&self) -> Losses {
        self.clone().finish()
    }

    /// A decoded item, in stream order: a banner starts a boot, a line of ours is
    /// counted (a record's counters read when it has them), other lines are not.
    pub fn item(&mut self, item: &Item) {
        match item {
            Item::Other(o) if is_banner(o) => self.banner(),
            Item::Other(_) => {}
            Item::Line(l) => {
                let record = (l.kind == "mras").then(|| match l.has_loss_counters() {
                    true => l.record().ok(),
                    false => None,
                });
                self.line(l.seq(), record.as_ref().map(Option::as_ref));
            }
        }
    }
}

/// The losses of hil-sim's stream of a power-up (init's `mras-paths` line, then the
/// supervisor's lines), as [`Decoded::losses`] counts them in its encoding.
pub fn losses_of(streamed: &[Streamed]) -> Losses {
    let mut c = LossCounter::default();
    c.banner();
    c.line(Some(INIT_SEQ), None);
    for s in streamed {
        let record = match &s.line {
            StreamLine::Record(r) => Some(Some(r)),
            _ => None,
        };
        c.line(Some(s.seq), record);
    }
    c.finish()
}

impl Decoded {
    /// What the stream lost: the drive's counters from the records, frames from `seq`.
    pub fn losses(&self) -> Losses {
        let mut c = LossCounter::default();
        for item in &self.items {
            c.item(item);
        }
        c.finish()
    }
}

/// The ELF's defmt table (the decoder's input besides the bytes).
pub fn table(elf: &[u8]) -> Result<Table> {
    Table::parse(elf)
        .context("reading the defmt table")?
        .ok_or_else(|| anyhow!("the ELF has no defmt table"))
}

/// One frame of the stream as [`StreamDecoder`] yields it.
#[derive(Clone, Debug, PartialEq)]
pub enum Frame {
    /// A decoded frame (a line of ours or another log line).
    Item(Item),
    /// A frame the decoder could not decode (corrupt or truncated bytes).
    Malformed,
    /// A line of ours whose fields did not fit the schema, with the reason.
    BadLine(String),
}

/// Decodes a stream as its bytes arrive (a live RTT capture): bytes in with
/// [`received`](Self::received), frames out with [`next_frame`](Self::next_frame).
/// Frames are rzCOBS-framed, so how the bytes were chunked does not change what
/// decodes: [`decode`] is this over the whole capture at once.
pub struct StreamDecoder<'t> {
    dec: Box<dyn defmt_decoder::StreamDecoder + 't>,
}

impl<'t> StreamDecoder<'t> {
    pub fn new(table: &'t Table) -> Self {
        Self {
            dec: table.new_stream_decoder(),
        }
    }

    /// More bytes of the stream, in order.
    pub fn received(&mut self, bytes: &[u8]) {
        self.dec.received(bytes);
    }

    /// The next complete frame, None until more bytes arrive.
    pub fn next_frame(&mut self) -> Option<Frame> {
        match self.dec.decode() {
            Ok(frame) => {
                let frags = frame.fragments();
                // The rendering of each parameter on its own, in order.
                let texts = frags
                    .iter()
                    .zip(frame.display_fragments())
                    .filter(|(f, _)| matches!(f, Fragment::Parameter(_)))
                    .map(|(_, t)| t);
                Some(match line_of(&frags, texts) {
                    Ok(Some(l)) => Frame::Item(Item::Line(l)),
                    Ok(None) => Frame::Item(Item::Other(frame.display_message().to_string())),
                    Err(e) => Frame::BadLine(format!("{e:#}")),
                })
            }
            Err(DecodeError::UnexpectedEof) => None,
            Err(DecodeError::Malformed) => Some(Frame::Malformed),
        }
    }
}

impl Decoded {
    /// A frame, in stream order.
    pub fn push(&mut self, frame: Frame) {
        match frame {
            Frame::Item(i) => self.items.push(i),
            Frame::Malformed => self.malformed += 1,
            Frame::BadLine(b) => self.bad_lines.push(b),
        }
    }
}

/// Decode a raw defmt byte stream (RTT channel 0) against the ELF that produced it.
pub fn decode(elf: &[u8], bytes: &[u8]) -> Result<Decoded> {
    let table = table(elf)?;
    let mut dec = StreamDecoder::new(&table);
    dec.received(bytes);
    let mut out = Decoded::default();
    while let Some(frame) = dec.next_frame() {
        out.push(frame);
    }
    Ok(out)
}

/// The ELF's format strings of our lines: (index, format) by marker.
pub struct Formats {
    by_kind: Vec<(String, u16, String)>,
}

impl Formats {
    /// Read the log statements' format strings from the ELF's `.defmt` symbols (each
    /// symbol's address is the index the firmware sends; its name is JSON).
    pub fn from_elf(elf: &[u8]) -> Result<Self> {
        use object::{Object, ObjectSection, ObjectSymbol};
        let file = object::File::parse(elf).context("parsing the ELF")?;
        let defmt_section = |n: &str| n == ".defmt" || n.starts_with(".defmt.");
        let defmt: Vec<_> = (file.sections())
            .filter(|s| s.name().is_ok_and(defmt_section))
            .map(|s| s.index())
            .collect();
        let mut by_kind = Vec::new();
        let in_defmt = |s: &object::Symbol| s.section_index().is_some_and(|i| defmt.contains(&i));
        for sym in file.symbols().filter(in_defmt) {
            let json: Option<Json> = sym.name().ok().and_then(|n| serde_json::from_str(n).ok());
            let Some(json) = json else { continue };
            let tag = json["tag"].as_str().unwrap_or("");
            let data = json["data"].as_str().unwrap_or("");
            let word = data.split_whitespace().next().unwrap_or("");
            if matches!(tag, "defmt_info" | "defmt_error" | "defmt_warn") && is_ours(word) {
                let index = u16::try_from(sym.address())
                    .map_err(|_| anyhow!("defmt index {:#x} beyond u16", sym.address()))?;
                by_kind.push((word.to_string(), index, data.to_string()));
            }
        }
        if by_kind.is_empty() {
            bail!("the ELF has no `mras` log statement: not the drive firmware, or DEFMT_LOG filtered them out");
        }
        Ok(Self { by_kind })
    }

    fn get(&self, kind: &str) -> Result<(u16, &str)> {
        match self
            .by_kind
            .iter()
            .filter(|(k, _, _)| k == kind)
            .collect::<Vec<_>>()[..]
        {
            [(_, index, format)] => Ok((*index, format)),
            [] => bail!("the ELF has no `{kind}` log statement"),
            _ => bail!("the ELF has two `{kind}` log statements"),
        }
    }

    /// One frame of `kind` with `fields` in the format's order, rzCOBS-framed as defmt-rtt
    /// sends it (no timestamp: the firmware defines none). The names the format gives its
    /// parameters must be the fields' names.
    pub fn encode<'k>(
        &self,
        kind: &str,
        fields: impl IntoIterator<Item = (&'k str, Value)>,
        out: &mut Vec<u8>,
    ) -> Result<()> {
        let fields: Vec<(&str, Value)> = fields.into_iter().collect();
        let (index, format) = self.get(kind)?;
        let frags = defmt_parser::parse(format, ParserMode::Strict)
            .map_err(|e| anyhow!("`{format}`: {e:?}"))?;
        let (_, params) = schema(&frags)?.ok_or_else(|| anyhow!("`{format}` is not ours"))?;
        if params.len() != fields.len() {
            bail!(
                "`{kind}`: the format has {} parameters, the schema {} fields",
                params.len(),
                fields.len()
            );
        }
        let mut raw = index.to_le_bytes().to_vec();
        for ((key, ty), (name, v)) in params.iter().zip(&fields) {
            if key != name {
                bail!("`{kind}`: parameter `{key}` where the schema has `{name}`");
            }
            encode_param(ty, v, &mut raw).with_context(|| format!("`{kind}` `{name}`"))?;
        }
        let mut enc = defmt::Encoder::new();
        enc.start_frame(|b| out.extend_from_slice(b));
        enc.write(&raw, |b| out.extend_from_slice(b));
        enc.end_frame(|b| out.extend_from_slice(b));
        Ok(())
    }

    /// A `mras-paths` line naming the coefficient columns (init's is `seq` INIT_SEQ).
    pub fn encode_paths(&self, seq: u32, names: &str, out: &mut Vec<u8>) -> Result<()> {
        let fields = [
            (SEQ_KEY, Value::Uint(seq.into())),
            ("paths", Value::Str(names.into())),
        ];
        self.encode("mras-paths", fields, out)
    }
}

/// The stream a simulated power-up would have sent (without the banner, which is not
/// ours): init's `mras-paths` line, then the supervisor's lines in order, each with its
/// `seq`.
pub fn encode_streamed(formats: &Formats, path_names: &str, items: &[Streamed]) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    formats.encode_paths(INIT_SEQ, path_names, &mut out)?;
    let named = |(k, v): (&'static str, FieldValue)| (k, Value::from(v));
    for s in items {
        let seq = std::iter::once((SEQ_KEY, Value::Uint(s.seq.into())));
        match &s.line {
            StreamLine::Record(r) => {
                formats.encode("mras", seq.chain(r.fields().map(named)), &mut out)?
            }
            StreamLine::Event(e) => {
                let fields = seq.chain(e.fields().into_iter().map(named));
                formats.encode(e.kind(), fields, &mut out)?
            }
            StreamLine::Paths(b) => {
                let names = drive::telemetry::bank_names(b.as_slice());
                formats.encode_paths(s.seq, &names, &mut out)?
            }
        }
    }
    Ok(out)
}

/// The release firmware ELF of the checkout the command runs in.
pub fn release_elf() -> PathBuf {
    crate::checkout::release_elf()
}

/// A value in defmt's wire format for its parameter type (little-endian, str as a u32
/// length and the bytes, bool as one byte).
fn encode_param(ty: &Type, v: &Value, raw: &mut Vec<u8>) -> Result<()> {
    match (ty, v) {
        (Type::U8, Value::Uint(x)) => raw.push(u8::try_from(*x)?),
        (Type::U16, Value::Uint(x)) => raw.extend(u16::try_from(*x)?.to_le_bytes()),
        (Type::U32, Value::Uint(x)) => raw.extend(u32::try_from(*x)?.to_le_bytes()),
        (Type::F32, Value::F32(x)) => raw.extend(x.to_bits().to_le_bytes()),
        (Type::Bool, Value::Bool(x)) => raw.push(*x as u8),
        (Type::Str, Value::Str(s)) => {
            raw.extend(u32::try_from(s.len())?.to_le_bytes());
            raw.extend(s.as_bytes());
        }
        (ty, v) => bail!("a {v:?} for a {ty:?} parameter"),
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(format: &str, texts: &[&str]) -> Result<Option<Line>> {
        let frags = defmt_parser::parse(format, ParserMode::Strict).unwrap();
        line_of(&frags, texts.iter().map(|t| t.to_string()))
    }

    #[test]
    fn lines_take_names_from_the_literals_and_lists_continue() {
        let l = line(
            "mras t_ms={=u32} ok={=bool} coef={=f32},{=f32}",
            &["12", "true", "0.5", "-1e-7"],
        )
        .unwrap()
        .unwrap();
        assert_eq!(l.kind, "mras");
        assert_eq!(
            l.fields,
            [
                ("t_ms".to_string(), Value::Uint(12)),
                ("ok".to_string(), Value::Bool(true)),
                ("coef".to_string(), Value::F32(0.5)),
                ("coef".to_string(), Value::F32(-1e-7)),
            ]
        );
        assert_eq!(l.t_ms(), Some(12));
        let p = line("mras-paths {=str}", &["offset,h4"]).unwrap().unwrap();
        assert_eq!(p.paths().unwrap(), ["offset", "h4"]);
    }

    #[test]
    fn other_lines_are_not_ours_and_bad_values_are_named() {
        assert_eq!(line("drive-fw: {=u32} Hz", &["1"]).unwrap(), None);
        let e = line("mras t_ms={=u32}", &["x1"]).unwrap_err();
        assert!(format!("{e:#}").contains("`t_ms`"), "{e:#}");
        let e = line("mras t_ms={=u32} junk {=u32}", &["1", "2"]).unwrap_err();
        assert!(format!("{e:#}").contains("junk"), "{e:#}");
    }

    fn record() -> Record {
        Record {
            t_ms: 5,
            state: State::Adapt,
            faults: 0,
            theta_rad: 1.5,
            omega_rad_s: 125.0,
            amplitude: 1.0,
            converged: false,
            revs: 3,
            residual_max_rad: 1e-3,
            cycles_max: 0,
            cycles_mean: 0,
            cycles_min: 0,
            handoffs_dropped: 0,
            updates_dropped: 0,
            updates_late: 0,
            events_dropped: 0,
            coef: [0.25; 2 * MAX_PATHS],
        }
    }

    fn record_line(seq: u32, r: &Record) -> Line {
        let seq = (SEQ_KEY.to_string(), Value::Uint(seq.into()));
        let fields = r.fields().map(|(k, v)| (k.into(), v.into()));
        Line {
            kind: "mras".into(),
            fields: std::iter::once(seq).chain(fields).collect(),
        }
    }

    #[test]
    fn record_lines_check_the_schema() {
        let r = record();
        let line = record_line(7, &r);
        assert_eq!(line.record().unwrap(), r);
        assert_eq!(line.seq(), Some(7));
        let mut short = line.clone();
        short.fields.pop();
        assert!(format!("{:#}", short.record().unwrap_err()).contains("coef"));
        let mut unknown = line.clone();
        unknown.fields.push(("speed".into(), Value::F32(1.0)));
        assert!(format!("{:#}", unknown.record().unwrap_err()).contains("speed"));
        // The earlier firmware's 8 paths: the rest reads as unused paths.
        let mut eight_paths = line.clone();
        eight_paths
            .fields
            .truncate(eight_paths.fields.len() - MAX_PATHS);
        let mut padded = r;
        padded.coef[MAX_PATHS..].fill(0.0);
        assert_eq!(eight_paths.record().unwrap(), padded);
        let mut state = line.clone();
        state.fields[2].1 = Value::Str("Spinning".into());
        assert!(format!("{:#}", state.record().unwrap_err()).contains("Spinning"));
        // A firmware from before seq, θ̂ and the loss counters: θ̂ unknown (NaN), the
        // counters 0, and the line says it has none.
        let older_keys = [SEQ_KEY, "theta_rad", "handoffs_dropped", "updates_dropped"];
        let older_keys = [&older_keys[..], &["updates_late", "events_dropped"]].concat();
        let mut older = line;
        older
            .fields
            .retain(|(k, _)| !older_keys.contains(&k.as_str()));
        let got = older.record().unwrap();
        assert!(got.theta_rad.is_nan());
        assert_eq!(
            Record {
                theta_rad: r.theta_rad,
                ..got
            },
            r
        );
        assert!(!older.has_loss_counters() && older.seq().is_none());
    }

    fn event(seq: Option<u32>) -> Item {
        let mut fields = vec![("state".to_string(), Value::Str("Run".into()))];
        fields.extend(seq.map(|s| (SEQ_KEY.to_string(), Value::Uint(s.into()))));
        Item::Line(Line {
            kind: "mras-state".into(),
            fields,
        })
    }

    fn banner() -> Item {
        Item::Other("drive-fw: 20000 Hz PWM, SYSCLK 170000000 Hz, N = 2, p = 4".into())
    }

    fn rec(seq: u32, f: impl Fn(&mut Record)) -> Item {
        let mut r = record();
        f(&mut r);
        Item::Line(record_line(seq, &r))
    }

    fn losses(items: Vec<Item>) -> Losses {
        Decoded {
            items,
            ..Decoded::default()
        }
        .losses()
    }

    #[test]
    fn losses_count_seq_gaps_and_each_boots_last_counters() {
        assert!(losses(vec![]).is_none());
        assert_eq!(losses(vec![]).describe(), "none");
        // One boot, nothing lost.
        let clean = losses(vec![
            banner(),
            event(Some(0)),
            rec(1, |_| {}),
            event(Some(2)),
        ]);
        assert!(clean.is_none(), "{clean:?}");
        assert_eq!(clean.boots, 1);
        let items = vec![
            banner(),
            event(Some(0)),
            rec(1, |r| r.handoffs_dropped = 1),
            // seq 2 lost
            rec(3, |r| {
                r.handoffs_dropped = 2;
                r.updates_late = 5;
            }),
            // A reset: the banner, init's line (seq 0) lost, then seq 1.
            banner(),
            rec(1, |r| r.updates_dropped = 3),
            event(Some(2)),
            // The banner of the next boot lost: seq goes back; its seq 0..1 lost too.
            rec(2, |r| r.events_dropped = 4),
        ];
        let l = losses(items);
        assert_eq!(
            l,
            Losses {
                handoffs_dropped: 2,
                updates_dropped: 3,
                updates_late: 5,
                events_dropped: 4,
                frames_lost: 1 + 1 + 2,
                boots: 3,
                uncounted_lines: 0,
            }
        );
        assert!(l.describe().contains("4 frames lost"), "{}", l.describe());
        // A capture that starts mid-boot: nothing before its first line is counted.
        let mid = losses(vec![rec(40, |_| {}), event(Some(41))]);
        assert!(mid.is_none(), "{mid:?}");
        // Lines of a firmware from before seq: unknown, not zero.
        let old = losses(vec![banner(), event(None)]);
        assert_eq!(old.uncounted_lines, 1);
        assert!(!old.is_none());
    }
}
