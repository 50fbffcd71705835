//! `hil-sim probe`: flash the drive firmware, capture its RTT stream raw and decode it
//! live, on a bench probe or (in CI) the emulator's virtual probe, with the `probe-rs`
//! library. It replaces OpenOCD's RTT server + `nc` (`probe-rs run` prints decoded text
//! only, and `rtt-log` needs the raw defmt bytes).
//!
//! Every function below takes a [`Probe`] or a `&mut` [`Session`]: nothing
//! assumes a USB probe, so the emulator's virtual probe is attached exactly like a real
//! one ([`attach`]) and the workflows take a closure that opens the session.
//!
//! - [`list_and_select`] (`--probe SERIAL`): the connected probes, one chosen by
//!   [`choose_probe`] (none, several without `--probe`, or the serial not found are
//!   errors that say what to check and list what is there).
//! - [`attach`]: a session on the chip, refused unless DBGMCU_IDCODE's DEV_ID is 0x469
//!   (STM32G47x/G48x, [`check_dev_id`]): a G431 or G491 on the bench would take the
//!   flash but not the firmware.
//! - [`flash`]: the ELF's load segments programmed and verified, progress on stderr.
//!   probe-rs erases only the 2 KiB sectors the ELF occupies (no chip erase is ever
//!   asked for): the calibration pages at the top of bank 2, which the ELF leaves
//!   empty, survive a reflash.
//! - [`running_matches_elf`]: before recording a drive that was not flashed here, its
//!   flash is compared with the ELF's load segments (by physical address): a stream is
//!   decoded with the ELF's defmt table, so a different firmware would decode to
//!   nonsense.
//! - [`record`]: RTT up channel 0 read raw every few milliseconds, decoded as it
//!   arrives ([`stream::StreamDecoder`], the code path `rtt-log` uses), a [`LiveStatus`]
//!   kept and shown on stderr; it ends when the caller's `stop` says so, on Ctrl-C, or
//!   when the probe stops answering ([`Ended::ProbeLost`]) — the bytes captured so far
//!   are always returned, never dropped.
//! - [`write_recording`]: `NAME.defmt` (the raw bytes, written first and always), then
//!   `rtt-log`'s CSV, event table and plots.
//! - Workflows: [`power_up`] (flash, commissioning power-up to `Run` and a hold, reflash,
//!   reboot to `Run` with the stored calibration) and [`attach_and_record`] (a running
//!   drive, optionally reset).
//!
//! Attaching halts the core briefly: probe-rs halts, steps and resumes it when a
//! session opens and closes (it clears the hardware breakpoints). With the debug freeze
//! TIM1 stops and the bridge is off for that moment; do not attach to a drive under load.
//!
//! On the bench:
//!
//! ```text
//! hil-sim probe flash [--reset]                       # flash + verify this checkout's release ELF
//! hil-sim probe power-up [--hold-s 2] [--timeout-s 120] [--out target/bench]
//! hil-sim probe attach [--reset] [--duration-s 60] [--name attach]
//!   common: --elf PATH  --probe SERIAL  --chip STM32G474RETx  --status auto|redraw|lines|off
//! ```
//!
//! Outputs per recording in `--out`: `NAME.defmt` (raw; `hil-sim rtt-log --input` reads
//! it again), `NAME.csv` (+ `NAME.2.csv`.. after a reset), `NAME.events.csv`,
//! `plots-NAME/`.
//!
//! Ctrl-C during a flash lets the flash finish (a half-programmed chip is worse), then
//! stops; during a recording it ends it and the capture is written.

use crate::rtt_log;
use crate::stream::{self, Frame, Item, Line, LossCounter, Losses, StreamDecoder};
use anyhow::{anyhow, bail, Context, Result};
use drive::commissioning::State;
use probe_rs::flashing::{
    download_file_with_options, DownloadOptions, ElfLoader, ElfOptions, FlashProgress,
    ProgressEvent, ProgressOperation,
};
use probe_rs::probe::list::{Accessibility, Lister};
use probe_rs::probe::{DebugProbeInfo, Probe};
use probe_rs::rtt::{Rtt, ScanRegion};
use probe_rs::{Core, MemoryInterface, Permissions, Session};
use std::fmt::Write as _;
use std::fs;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// probe-rs's name of the drive's chip.
pub const DEFAULT_CHIP: &str = "STM32G474RETx";
/// DBGMCU_IDCODE: DEV_ID in bits 11:0, REV_ID in 31:16 (RM0440 46.6.1).
pub const DBGMCU_IDCODE: u64 = 0xE004_2000;
/// DEV_ID of the STM32G47x/G48x (category 3), the chip the firmware is built for.
pub const DEV_ID_G47X: u16 = 0x469;

// ---------------------------------------------------------------------------------
// Probe choice
// ---------------------------------------------------------------------------------

fn describe_probe(p: &DebugProbeInfo) -> String {
    format!(
        "{} (serial {}, {:04x}:{:04x})",
        p.identifier,
        p.serial_number.as_deref().unwrap_or("none"),
        p.vendor_id,
        p.product_id
    )
}

fn probe_list(probes: &[DebugProbeInfo]) -> String {
    probes
        .iter()
        .map(|p| format!("\n  {}", describe_probe(p)))
        .collect()
}

/// Which of `probes` to open: the one there is, or the one whose serial number is
/// `serial`. The errors say what to check and list the probes found.
pub fn choose_probe(probes: &[DebugProbeInfo], serial: Option<&str>) -> Result<usize> {
    match (serial, probes) {
        (_, []) => bail!(
            "no debug probe found: check the probe's USB cable, that your user may open it \
             (udev rules on Linux: https://probe.rs/docs/getting-started/probe-setup/), and \
             what `probe-rs list` shows"
        ),
        (None, [_]) => Ok(0),
        (None, _) => bail!(
            "{} debug probes connected; choose one with `--probe SERIAL`:{}",
            probes.len(),
            probe_list(probes)
        ),
        (Some(s), _) => {
            let found: Vec<usize> = (0..probes.len())
                .filter(|&i| probes[i].serial_number.as_deref() == Some(s))
                .collect();
            match found[..] {
                [i] => Ok(i),
                [] => bail!(
                    "no debug probe with serial number `{s}`; connected:{}",
                    probe_list(probes)
                ),
                _ => bail!(
                    "{} debug probes share the serial number `{s}` (unplug all but one):{}",
                    found.len(),
                    probe_list(probes)
                ),
            }
        }
    }
}

/// The connected debug probes, one chosen by [`choose_probe`], opened.
pub fn list_and_select(serial: Option<&str>) -> Result<Probe> {
    let items = Lister::new().list_all_with_access();
    let infos: Vec<DebugProbeInfo> = items.iter().map(|i| i.info.clone()).collect();
    let i = choose_probe(&infos, serial)?;
    if items[i].accessibility == Accessibility::PermissionDenied {
        bail!(
            "{}: found but not accessible to this user: install probe-rs's udev rules \
             (https://probe.rs/docs/getting-started/probe-setup/) and replug the probe",
            describe_probe(&infos[i])
        );
    }
    infos[i].open().with_context(|| {
        format!(
            "{}: cannot open (another program using it? OpenOCD, probe-rs, an IDE)",
            describe_probe(&infos[i])
        )
    })
}

// ---------------------------------------------------------------------------------
// Chip check
// ---------------------------------------------------------------------------------

/// A G4 part's name by DEV_ID, for messages.
fn g4_part(dev_id: u16) -> Option<&'static str> {
    match dev_id {
        0x468 => Some("STM32G431/G441"),
        0x469 => Some("STM32G47x/G48x"),
        0x479 => Some("STM32G491/G4A1"),
        _ => None,
    }
}

/// Whether a DBGMCU_IDCODE value is the chip the firmware is built for (DEV_ID 0x469):
/// the error names what was found.
pub fn check_dev_id(idcode: u32) -> Result<()> {
    let dev_id = (idcode & 0xFFF) as u16;
    let rev_id = idcode >> 16;
    if dev_id == DEV_ID_G47X {
        return Ok(());
    }
    if idcode == 0 || idcode == u32::MAX {
        bail!(
            "DBGMCU_IDCODE reads {idcode:#010x}: no device ID (is the board powered, the SWD \
             cable on the right header, NRST not held?)"
        );
    }
    let found = match g4_part(dev_id) {
        Some(name) => format!("{name} (DEV_ID {dev_id:#05x}, rev {rev_id:#06x})"),
        None => format!("an unknown part (DEV_ID {dev_id:#05x}, rev {rev_id:#06x})"),
    };
    bail!(
        "wrong chip: the firmware is built for the STM32G474RE (DEV_ID {DEV_ID_G47X:#05x}), \
         the probe reached {found}; check which board the probe is plugged into"
    )
}

/// A session on `chip` through `probe`, refused unless the chip is an STM32G47x
/// ([`check_dev_id`]).
pub fn attach(probe: Probe, chip: &str) -> Result<Session> {
    let mut session = probe
        .attach(chip, Permissions::default())
        .with_context(|| {
            format!(
                "attaching to {chip}: check the SWD cable, the board's power and that --chip \
             names it"
            )
        })?;
    let idcode = session
        .core(0)
        .and_then(|mut c| c.read_word_32(DBGMCU_IDCODE))
        .context("reading DBGMCU_IDCODE")?;
    check_dev_id(idcode)?;
    Ok(session)
}

// ---------------------------------------------------------------------------------
// Flash
// ---------------------------------------------------------------------------------

/// What [`flash`] did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FlashReport {
    pub sectors_erased: u64,
    pub bytes_erased: u64,
    pub pages_programmed: u64,
    pub bytes_programmed: u64,
    pub bytes_verified: u64,
    pub seconds: f64,
}

impl FlashReport {
    pub fn describe(&self) -> String {
        format!(
            "{} sectors erased ({} KiB), {} pages programmed ({} bytes), {} bytes verified, {:.1} s",
            self.sectors_erased,
            self.bytes_erased / 1024,
            self.pages_programmed,
            self.bytes_programmed,
            self.bytes_verified,
            self.seconds
        )
    }
}

/// Flash progress as counted from probe-rs's events, drawn as one line.
#[derive(Default)]
struct FlashCounts {
    report: FlashReport,
    /// Totals announced per operation (bytes): erase, program, verify.
    totals: [Option<u64>; 3],
    phase: &'static str,
    redraw: bool,
    show: bool,
}

impl FlashCounts {
    fn on(&mut self, ev: ProgressEvent) {
        let slot = |op: ProgressOperation| match op {
            ProgressOperation::Erase => Some(0),
            ProgressOperation::Program => Some(1),
            ProgressOperation::Verify => Some(2),
            ProgressOperation::Fill => None,
        };
        match ev {
            ProgressEvent::AddProgressBar { operation, total } => {
                // One bar per flash region and operation: the totals add up.
                if let (Some(i), Some(t)) = (slot(operation), total) {
                    self.totals[i] = Some(self.totals[i].unwrap_or(0) + t);
                }
            }
            ProgressEvent::Started(op) => {
                self.phase = match op {
                    ProgressOperation::Erase => "erasing",
                    ProgressOperation::Program => "programming",
                    ProgressOperation::Verify => "verifying",
                    ProgressOperation::Fill => "reading back",
                };
                self.draw(false);
            }
            ProgressEvent::Progress {
                operation, size, ..
            } => {
                let r = &mut self.report;
                match operation {
                    ProgressOperation::Erase => {
                        r.sectors_erased += 1;
                        r.bytes_erased += size;
                    }
                    ProgressOperation::Program => {
                        r.pages_programmed += 1;
                        r.bytes_programmed += size;
                    }
                    ProgressOperation::Verify => r.bytes_verified += size,
                    ProgressOperation::Fill => {}
                }
                self.draw(false);
            }
            ProgressEvent::Finished(_) => self.draw(true),
            ProgressEvent::Failed(op) => {
                self.phase = match op {
                    ProgressOperation::Erase => "erase FAILED",
                    ProgressOperation::Program => "programming FAILED",
                    ProgressOperation::Verify => "verify FAILED",
                    ProgressOperation::Fill => "read-back FAILED",
                };
                self.draw(true);
            }
            ProgressEvent::DiagnosticMessage { message } => {
                if self.show {
                    eprintln!("\nflash algorithm: {message}");
                }
            }
            ProgressEvent::FlashLayoutReady { .. } => {}
        }
    }

    fn line(&self) -> String {
        let r = &self.report;
        let of = |i: usize| match self.totals[i] {
            Some(t) => format!("/{} KiB", t.div_ceil(1024)),
            None => String::new(),
        };
        format!(
            "flash: {:<12} erased {} sectors ({} KiB{}), programmed {} pages ({} KiB{}), verified {} KiB{}",
            self.phase,
            r.sectors_erased,
            r.bytes_erased / 1024,
            of(0),
            r.pages_programmed,
            r.bytes_programmed / 1024,
            of(1),
            r.bytes_verified / 1024,
            of(2)
        )
    }

    fn draw(&self, phase_done: bool) {
        if !self.show {
            return;
        }
        // A terminal gets one line redrawn in place; a log a line per finished phase.
        if self.redraw {
            eprint!("\r{}\x1b[K", self.line());
        } else if phase_done {
            eprintln!("{}", self.line());
        }
    }
}

/// Program and verify the ELF's load segments, with progress on stderr when
/// `progress`.
///
/// Never a chip or bank erase: probe-rs erases only the sectors the ELF's data falls in
/// (`do_chip_erase` stays off), so the calibration pages at the top of bank 2
/// (0x0807F000..), which the ELF leaves empty, keep the stored calibration.
pub fn flash(session: &mut Session, elf_path: &Path, progress: bool) -> Result<FlashReport> {
    let start = Instant::now();
    let mut counts = FlashCounts {
        phase: "preparing",
        redraw: std::io::stderr().is_terminal(),
        show: progress,
        ..FlashCounts::default()
    };
    let result = {
        let mut options = DownloadOptions::default();
        options.verify = true;
        options.do_chip_erase = false;
        options.progress = FlashProgress::new(|ev| counts.on(ev));
        download_file_with_options(session, elf_path, ElfLoader(ElfOptions::default()), options)
    };
    if progress && counts.redraw {
        eprintln!();
    }
    result.with_context(|| {
        format!(
            "flashing {}: the drive's firmware may now be incomplete; flash again before \
             running the drive (check the SWD cable and the board's power)",
            elf_path.display()
        )
    })?;
    let mut report = counts.report;
    report.seconds = start.elapsed().as_secs_f64();
    Ok(report)
}

// ---------------------------------------------------------------------------------
// Running firmware vs ELF
// ---------------------------------------------------------------------------------

/// Bytes the ELF puts in memory at a physical (load) address.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadSegment {
    pub paddr: u64,
    pub data: Vec<u8>,
}

/// The ELF's `PT_LOAD` segments with file data, by physical address (p_paddr: where a
/// probe writes them; `.data`'s image in flash, not its RAM address).
pub fn load_segments(elf: &[u8]) -> Result<Vec<LoadSegment>> {
    use object::read::elf::{FileHeader, ProgramHeader};
    let header = object::elf::FileHeader32::<object::Endianness>::parse(elf)
        .context("not a 32-bit ELF: the firmware is built for thumbv7em")?;
    let e = header.endian().context("ELF endianness")?;
    let mut out = Vec::new();
    for ph in header
        .program_headers(e, elf)
        .context("ELF program headers")?
    {
        if ph.p_type(e) != object::elf::PT_LOAD || ph.p_filesz(e) == 0 {
            continue;
        }
        let data = ph.data(e, elf).map_err(|()| {
            anyhow!(
                "ELF segment at {:#010x} lies outside the file",
                ph.p_paddr(e)
            )
        })?;
        out.push(LoadSegment {
            paddr: ph.p_paddr(e).into(),
            data: data.to_vec(),
        });
    }
    if out.is_empty() {
        bail!("the ELF has no loadable data");
    }
    Ok(out)
}

/// Where the running firmware first differs from the ELF.
#[derive(Clone, Debug, PartialEq)]
pub struct Difference {
    pub addr: u64,
    pub expected: u8,
    pub found: u8,
}

/// Bytes compared per read: a mismatch near the start stops early.
const COMPARE_CHUNK: usize = 1024;

/// The first address where memory (through `read`) differs from `segments`, in
/// address order; None when all match.
pub fn first_difference(
    segments: &[LoadSegment],
    read: &mut dyn FnMut(u64, &mut [u8]) -> Result<()>,
) -> Result<Option<Difference>> {
    let mut sorted: Vec<&LoadSegment> = segments.iter().collect();
    sorted.sort_by_key(|s| s.paddr);
    let mut buf = vec![0u8; COMPARE_CHUNK];
    for seg in sorted {
        for (k, want) in seg.data.chunks(COMPARE_CHUNK).enumerate() {
            let addr = seg.paddr + (k * COMPARE_CHUNK) as u64;
            let got = &mut buf[..want.len()];
            read(addr, got).with_context(|| format!("reading {addr:#010x}"))?;
            if let Some(i) = (0..want.len()).find(|&i| want[i] != got[i]) {
                return Ok(Some(Difference {
                    addr: addr + i as u64,
                    expected: want[i],
                    found: got[i],
                }));
            }
        }
    }
    Ok(None)
}

/// Refuse when the firmware in the chip's flash is not `elf`: its defmt table would not
/// decode the stream. Only the segments in the target's non-volatile memory are
/// compared (RAM is the running program's).
pub fn running_matches_elf(session: &mut Session, elf: &[u8]) -> Result<()> {
    let nvm: Vec<std::ops::Range<u64>> = session
        .target()
        .memory_map
        .iter()
        .filter_map(|r| r.as_nvm_region())
        .map(|r| r.range.clone())
        .collect();
    let segments: Vec<LoadSegment> = load_segments(elf)?
        .into_iter()
        .filter(|s| nvm.iter().any(|r| r.contains(&s.paddr)))
        .collect();
    if segments.is_empty() {
        bail!("the ELF has nothing in the chip's flash: not the drive firmware");
    }
    let mut core = session.core(0).context("opening the core")?;
    let mut read = |addr: u64, buf: &mut [u8]| -> Result<()> { Ok(core.read(addr, buf)?) };
    match first_difference(&segments, &mut read)? {
        None => Ok(()),
        Some(d) => bail!(
            "the running firmware is not this ELF: flash at {:#010x} holds {:#04x}, the ELF \
             {:#04x}. Its stream would not decode against this ELF's defmt table: flash it \
             (`hil-sim probe flash`, or `attach --reset` after flashing) or pass the ELF that \
             is running with --elf",
            d.addr,
            d.found,
            d.expected
        ),
    }
}

// ---------------------------------------------------------------------------------
// Live decoding and status
// ---------------------------------------------------------------------------------

/// What the stream has shown so far.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LiveStatus {
    /// The supervisor's last state (records and state events).
    pub state: Option<State>,
    /// The firmware's own time (`t_ms` of the last line that had one).
    pub t_ms: Option<u32>,
    /// The firmware time `Run` was entered in this boot.
    pub run_since_ms: Option<u32>,
    /// Fault bits of the last record.
    pub faults: u8,
    /// The last fault event (`cause=.. state=..`).
    pub last_fault: Option<String>,
    pub residual_max_rad: f32,
    pub omega_rad_s: f32,
    pub converged: bool,
    /// The largest control-interrupt cycle count of any record.
    pub cycles_max: u32,
    /// The drive's loss counters and the gaps in `seq` ([`Losses`]).
    pub losses: Losses,
    pub records: u64,
    /// Lines of ours other than records and `mras-paths`.
    pub events: u64,
    pub other_lines: u64,
    pub malformed: u64,
    pub bad_lines: u64,
    pub bytes: u64,
    /// A `mras-loaded` event was seen (the stored calibration was loaded at boot).
    pub calibration_loaded: bool,
    /// Wall time since recording started.
    pub wall_s: f64,
}

impl LiveStatus {
    /// One status line.
    pub fn line(&self) -> String {
        let t = self
            .t_ms
            .map_or("-".into(), |t| format!("{:.3} s", f64::from(t) / 1000.0));
        let state = self.state.map_or("-", State::name);
        format!(
            "{state} t={t} faults={:#04x} residual={:.2e} rad omega={:.1} rad/s cycles_max={} \
             rec={} ev={} {} B losses: {}{}",
            self.faults,
            self.residual_max_rad,
            self.omega_rad_s,
            self.cycles_max,
            self.records,
            self.events,
            self.bytes,
            self.losses.describe(),
            match self.malformed + self.bad_lines {
                0 => String::new(),
                n => format!(", {n} bad frames"),
            }
        )
    }

    /// Firmware milliseconds spent in `Run` (None before it).
    pub fn in_run_ms(&self) -> Option<u32> {
        match (self.state, self.run_since_ms, self.t_ms) {
            (Some(State::Run), Some(since), Some(t)) => Some(t.saturating_sub(since)),
            _ => None,
        }
    }
}

/// A state the supervisor entered, at firmware time `t_ms`.
#[derive(Clone, Debug, PartialEq)]
pub struct StateChange {
    pub t_ms: u32,
    pub state: State,
}

/// Decodes a stream as it arrives and keeps its [`LiveStatus`], state sequence and
/// events (the same decoding `rtt-log` does, frame by frame).
pub struct Monitor<'t> {
    dec: StreamDecoder<'t>,
    losses: LossCounter,
    pub status: LiveStatus,
    pub states: Vec<StateChange>,
    /// Events (lines of ours other than records and `mras-paths`), in order.
    pub events: Vec<Line>,
}

impl<'t> Monitor<'t> {
    pub fn new(table: &'t defmt_decoder::Table) -> Self {
        Self {
            dec: StreamDecoder::new(table),
            losses: LossCounter::default(),
            status: LiveStatus::default(),
            states: Vec::new(),
            events: Vec::new(),
        }
    }

    /// More bytes; returns whether the state changed.
    pub fn feed(&mut self, bytes: &[u8]) -> bool {
        self.status.bytes += bytes.len() as u64;
        self.dec.received(bytes);
        let before = self.status.state;
        while let Some(frame) = self.dec.next_frame() {
            self.frame(frame);
        }
        self.status.losses = self.losses.so_far();
        self.status.state != before
    }

    fn frame(&mut self, frame: Frame) {
        let item = match frame {
            Frame::Malformed => return self.status.malformed += 1,
            Frame::BadLine(_) => return self.status.bad_lines += 1,
            Frame::Item(i) => i,
        };
        self.losses.item(&item);
        let l = match item {
            Item::Other(o) => {
                if stream::is_banner(&o) {
                    // A new boot: its time starts again.
                    self.status.run_since_ms = None;
                }
                return self.status.other_lines += 1;
            }
            Item::Line(l) => l,
        };
        if let Some(t) = l.t_ms() {
            if self.status.t_ms.is_some_and(|last| t < last) {
                // Time went back: a reset whose banner was lost.
                self.status.run_since_ms = None;
            }
            self.status.t_ms = Some(t);
        }
        let t_ms = l.t_ms().unwrap_or(0);
        let named_state = |l: &Line| match l.get("state") {
            Some(stream::Value::Str(s)) => State::from_name(s),
            _ => None,
        };
        match l.kind.as_str() {
            "mras" => match l.record() {
                Ok(r) => {
                    let s = &mut self.status;
                    s.records += 1;
                    s.faults = r.faults;
                    s.residual_max_rad = r.residual_max_rad;
                    s.omega_rad_s = r.omega_rad_s;
                    s.converged = r.converged;
                    s.cycles_max = s.cycles_max.max(r.cycles_max);
                    self.enter(r.state, r.t_ms);
                }
                Err(_) => self.status.bad_lines += 1,
            },
            "mras-paths" => {}
            kind => {
                self.status.events += 1;
                match kind {
                    "mras-state" => {
                        if let Some(s) = named_state(&l) {
                            self.enter(s, t_ms);
                        }
                    }
                    "mras-fault" => {
                        self.status.last_fault = Some(l.describe());
                        self.enter(State::Safe, t_ms);
                    }
                    "mras-loaded" => self.status.calibration_loaded = true,
                    _ => {}
                }
                self.events.push(l);
            }
        }
    }

    fn enter(&mut self, state: State, t_ms: u32) {
        if self.status.state == Some(state) {
            return;
        }
        self.status.state = Some(state);
        self.states.push(StateChange { t_ms, state });
        if state == State::Run && self.status.run_since_ms.is_none() {
            self.status.run_since_ms = Some(t_ms);
        }
    }
}

// ---------------------------------------------------------------------------------
// Recording
// ---------------------------------------------------------------------------------

/// How the live status is shown on stderr.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum StatusDisplay {
    /// Redraw one line on a terminal, a line per second or state change otherwise.
    #[default]
    Auto,
    /// One line redrawn in place (~5 Hz).
    Redraw,
    /// A line per second and per state change (CI logs).
    Lines,
    /// Nothing.
    Off,
}

/// How [`record`] runs.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// Wall seconds to wait for the firmware to write its RTT control block (after a
    /// reset it appears when the firmware's init has run).
    pub attach_timeout_s: f64,
    /// Pause between reads of an empty channel. Short: defmt-rtt drops what does not
    /// fit its buffer.
    pub poll_ms: u64,
    pub display: StatusDisplay,
    /// Stop on Ctrl-C (installs a process-wide handler once; see [`interrupted`]).
    pub ctrl_c: bool,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            attach_timeout_s: 5.0,
            poll_ms: 3,
            display: StatusDisplay::Auto,
            ctrl_c: false,
        }
    }
}

/// Why a recording ended.
#[derive(Clone, Debug, PartialEq)]
pub enum Ended {
    /// The caller's `stop` said so.
    Stopped,
    /// Ctrl-C.
    Interrupted,
    /// Reading the target failed (probe unplugged, target powered off): the reason.
    ProbeLost(String),
}

/// A capture: the raw bytes of RTT up channel 0 and what they showed.
#[derive(Clone, Debug)]
pub struct Recording {
    pub raw: Vec<u8>,
    pub ended: Ended,
    pub status: LiveStatus,
    pub states: Vec<StateChange>,
    pub events: Vec<Line>,
}

static INTERRUPTED: AtomicBool = AtomicBool::new(false);
static HANDLER: OnceLock<Option<String>> = OnceLock::new();

/// Whether Ctrl-C was pressed since the handler was installed (or [`clear_interrupt`]).
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

pub fn clear_interrupt() {
    INTERRUPTED.store(false, Ordering::SeqCst);
}

/// Ctrl-C sets a flag the recording loop polls, so the capture is written instead of
/// lost with the process; installed before flashing, a Ctrl-C during a flash lets it
/// finish (a half-programmed chip is worse) and stops before the recording. Installed
/// once per process; if another handler is already there (an embedding program's),
/// Ctrl-C is left to it, with a note.
pub fn catch_ctrl_c() {
    let failure = HANDLER.get_or_init(|| {
        ctrlc::set_handler(|| INTERRUPTED.store(true, Ordering::SeqCst))
            .err()
            .map(|e| e.to_string())
    });
    if let Some(e) = failure {
        eprintln!("note: Ctrl-C not caught ({e}): stop with --duration-s");
    }
}

/// The address of `_SEGGER_RTT` in the ELF.
pub fn rtt_address(elf: &[u8]) -> Result<u64> {
    probe_rs::rtt::find_rtt_control_block_in_raw_file(elf)
        .map_err(|e| anyhow!("reading the ELF's symbols: {e}"))?
        .ok_or_else(|| anyhow!("the ELF has no `_SEGGER_RTT` symbol: not a defmt-rtt firmware"))
}

/// Attach RTT at the ELF's control block, retrying until the firmware has written it.
fn attach_rtt(core: &mut Core, addr: u64, timeout_s: f64) -> Result<Rtt> {
    let deadline = Instant::now() + Duration::from_secs_f64(timeout_s.max(0.0));
    loop {
        let err = match Rtt::attach_region(core, &ScanRegion::Exact(addr)) {
            Ok(mut rtt) => match rtt.up_channel(0) {
                Some(_) => return Ok(rtt),
                None => anyhow!("the control block has no up channel 0"),
            },
            Err(e) => anyhow!(e),
        };
        if Instant::now() >= deadline {
            return Err(err.context(format!(
                "no RTT control block at {addr:#010x} after {timeout_s} s: is the firmware \
                 running (not halted, not in a HardFault), and is it this ELF?"
            )));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// Consecutive failed reads taken as the probe lost (a single one may be a transient
/// SWD fault).
const READ_RETRIES: u32 = 3;

/// Record RTT up channel 0 raw until `stop(&status)` is true, Ctrl-C (with
/// `opts.ctrl_c`), or the probe stops answering: then the capture so far is returned
/// with [`Ended::ProbeLost`], not an error. Errors are only for failures before the
/// first byte (no control block, bad ELF).
pub fn record(
    session: &mut Session,
    elf: &[u8],
    opts: &RecordOptions,
    stop: &mut dyn FnMut(&LiveStatus) -> bool,
) -> Result<Recording> {
    let table = stream::table(elf)?;
    let addr = rtt_address(elf)?;
    if opts.ctrl_c {
        catch_ctrl_c();
    }
    let mut core = session.core(0).context("opening the core")?;
    let mut rtt = attach_rtt(&mut core, addr, opts.attach_timeout_s)?;
    let mut read = |buf: &mut [u8]| match rtt.up_channel(0) {
        Some(channel) => channel.read(&mut core, buf).map_err(|e| e.to_string()),
        None => Err("RTT up channel 0 disappeared".into()),
    };
    Ok(record_from(&mut read, &table, opts, stop))
}

/// [`record`]'s loop over any reader of the channel (`read` fills a buffer and returns
/// the byte count, 0 when nothing is waiting, or why it failed): the capture, its
/// status and why it ended. Never an error: whatever was read is in the recording.
pub fn record_from(
    read: &mut dyn FnMut(&mut [u8]) -> std::result::Result<usize, String>,
    table: &defmt_decoder::Table,
    opts: &RecordOptions,
    stop: &mut dyn FnMut(&LiveStatus) -> bool,
) -> Recording {
    let mut monitor = Monitor::new(table);
    let mut raw = Vec::new();
    let mut buf = vec![0u8; 4096];
    let start = Instant::now();
    let redraw = match opts.display {
        StatusDisplay::Auto => std::io::stderr().is_terminal(),
        StatusDisplay::Redraw => true,
        StatusDisplay::Lines | StatusDisplay::Off => false,
    };
    let show = opts.display != StatusDisplay::Off;
    let period = Duration::from_millis(if redraw { 200 } else { 1000 });
    let mut last_draw: Option<Instant> = None;
    let mut failures = 0;
    let draw = |status: &LiveStatus| {
        if redraw {
            eprint!("\r{}\x1b[K", status.line());
        } else {
            eprintln!("[{:7.1} s] {}", status.wall_s, status.line());
        }
    };
    let ended = loop {
        monitor.status.wall_s = start.elapsed().as_secs_f64();
        if stop(&monitor.status) {
            break Ended::Stopped;
        }
        if opts.ctrl_c && interrupted() {
            break Ended::Interrupted;
        }
        let n = match read(&mut buf) {
            Ok(n) => {
                failures = 0;
                n.min(buf.len())
            }
            Err(e) => {
                failures += 1;
                if failures >= READ_RETRIES {
                    break Ended::ProbeLost(e);
                }
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        let changed = if n > 0 {
            raw.extend_from_slice(&buf[..n]);
            monitor.feed(&buf[..n])
        } else {
            false
        };
        if show && (changed || last_draw.is_none_or(|t| t.elapsed() >= period)) {
            last_draw = Some(Instant::now());
            draw(&monitor.status);
        }
        // A full buffer means more is waiting: read again at once.
        if n < buf.len() {
            std::thread::sleep(Duration::from_millis(opts.poll_ms));
        }
    };
    monitor.status.wall_s = start.elapsed().as_secs_f64();
    if show {
        draw(&monitor.status);
        if redraw {
            eprintln!();
        }
    }
    Recording {
        raw,
        ended,
        status: monitor.status,
        states: monitor.states,
        events: monitor.events,
    }
}

/// Halt, clear the RTT control block the last run left in RAM (so the next attach
/// cannot read a stale one: after the reset it is found only once the firmware wrote
/// it again), and reset the chip running.
pub fn reset_for_capture(session: &mut Session, elf: &[u8]) -> Result<()> {
    let addr = rtt_address(elf)?;
    let mut core = session.core(0).context("opening the core")?;
    core.halt(Duration::from_millis(500))
        .context("halting the core before the reset")?;
    Rtt::clear_control_block(&mut core, &ScanRegion::Exact(addr))
        .context("clearing the old RTT control block")?;
    core.reset().context("resetting the chip")?;
    Ok(())
}

/// The raw capture's path for `name` in `out_dir`.
pub fn raw_path(out_dir: &Path, name: &str) -> PathBuf {
    out_dir.join(format!("{name}.defmt"))
}

/// Write `NAME.defmt` (the raw bytes: first, and always) in `out_dir`, then decode it
/// as `hil-sim rtt-log` does into `NAME.csv`, `NAME.events.csv` and `plots-NAME/`. A
/// decoding failure is an error that names the raw file, which is kept.
pub fn write_recording(rec: &Recording, elf_path: &Path, out_dir: &Path, name: &str) -> Result<()> {
    fs::create_dir_all(out_dir).with_context(|| format!("{}: cannot create", out_dir.display()))?;
    let raw = raw_path(out_dir, name);
    fs::write(&raw, &rec.raw).with_context(|| format!("{}: cannot write", raw.display()))?;
    let args = rtt_log::Args {
        input: raw.clone(),
        elf: Some(elf_path.to_path_buf()),
        output: out_dir.join(format!("{name}.csv")),
        plots: Some(out_dir.join(format!("plots-{name}"))),
    };
    rtt_log::run(&args).with_context(|| {
        format!(
            "decoding the capture (the raw bytes are kept in {}; decode them again with \
             `hil-sim rtt-log --input {} --elf ...`)",
            raw.display(),
            raw.display()
        )
    })
}

/// Where the capture is, for messages: "the capture so far (N bytes) is kept in PATH",
/// or that it could not be written there.
fn kept(rec: &Recording, raw: &Path) -> String {
    let n = rec.raw.len();
    match fs::metadata(raw) {
        Ok(m) if m.len() == n as u64 => {
            format!(
                "the capture so far ({n} bytes) is kept in {}",
                raw.display()
            )
        }
        _ => format!(
            "the capture ({n} bytes) could NOT be written to {} (see below)",
            raw.display()
        ),
    }
}

/// A workflow's failure with what writing the outputs said, if that failed too (the
/// CSV not written, or the raw file itself).
fn with_written(e: anyhow::Error, written: &Result<()>) -> anyhow::Error {
    match written {
        Ok(()) => e,
        Err(w) => anyhow!("{e:#}\n  and writing the outputs failed: {w:#}"),
    }
}

/// Why a recording that ended early failed, naming the kept capture.
fn ended_error(rec: &Recording, raw: &Path) -> Option<anyhow::Error> {
    let kept = kept(rec, raw);
    match &rec.ended {
        Ended::Stopped => None,
        Ended::Interrupted => Some(anyhow!("interrupted (Ctrl-C); {kept}")),
        Ended::ProbeLost(why) => Some(anyhow!(
            "the probe stopped answering ({why}): check the probe's USB cable, the SWD cable \
             and the board's power; {kept}"
        )),
    }
}

// ---------------------------------------------------------------------------------
// Workflows
// ---------------------------------------------------------------------------------

/// How [`power_up`] runs.
#[derive(Clone, Debug)]
pub struct PowerUpOptions {
    /// Firmware seconds to record after `Run` is reached.
    pub hold_s: f64,
    /// Wall seconds a boot's recording (after its flash) may take to reach `Run` and
    /// hold.
    pub timeout_s: f64,
    pub record: RecordOptions,
    /// Flash progress on stderr.
    pub progress: bool,
}

impl Default for PowerUpOptions {
    fn default() -> Self {
        Self {
            hold_s: 2.0,
            timeout_s: 120.0,
            record: RecordOptions::default(),
            progress: true,
        }
    }
}

/// One boot of [`power_up`].
#[derive(Clone, Debug)]
pub struct BootReport {
    /// `power-up-1` or `power-up-2`: the outputs' names.
    pub name: String,
    pub raw_path: PathBuf,
    pub flash: FlashReport,
    pub states: Vec<StateChange>,
    pub events: Vec<Line>,
    pub losses: Losses,
    pub bytes: u64,
    pub wall_s: f64,
    /// The stream showed the stored calibration loaded (`mras-loaded`).
    pub calibration_loaded: bool,
}

impl BootReport {
    /// The state sequence as `Name@t_s`.
    pub fn state_sequence(&self) -> String {
        self.states
            .iter()
            .map(|s| format!("{}@{:.3}s", s.state.name(), f64::from(s.t_ms) / 1000.0))
            .collect::<Vec<_>>()
            .join(" -> ")
    }
}

#[derive(Clone, Debug)]
pub struct PowerUpReport {
    pub boots: Vec<BootReport>,
}

impl PowerUpReport {
    /// Whether the second boot loaded the calibration the first stored.
    pub fn calibration_loaded_on_reboot(&self) -> bool {
        self.boots.get(1).is_some_and(|b| b.calibration_loaded)
    }
}

/// The commissioning power-up and the reboot with its stored calibration: per boot,
/// flash the ELF (only its sectors: the calibration pages survive), reset, record until
/// the stream shows `Run` and then `hold_s` more firmware seconds, write `power-up-1`
/// / `power-up-2` in `out_dir`.
///
/// `open` gives a new session per boot: each boot starts from a fresh attach (probe-rs
/// runs the chip's debug sequence again), a probe lost in boot 1 is not reused, and the
/// emulator's virtual probe is opened the same way. Nothing is lost by closing between
/// boots: the reflash halts and resets the core anyway.
///
/// Errors name the boot, the last state seen and the kept capture's path: a timeout
/// before `Run`, the drive going to `Safe`, Ctrl-C, the probe lost.
pub fn power_up(
    open: &mut dyn FnMut() -> Result<Session>,
    elf_path: &Path,
    out_dir: &Path,
    opts: &PowerUpOptions,
) -> Result<PowerUpReport> {
    let elf = read_elf(elf_path)?;
    let hold_ms = (opts.hold_s.max(0.0) * 1000.0).round() as u32;
    let mut boots = Vec::new();
    for k in 1..=2 {
        let name = format!("power-up-{k}");
        let mut session = open().with_context(|| format!("{name}: opening the probe"))?;
        let flash_report =
            flash(&mut session, elf_path, opts.progress).with_context(|| name.clone())?;
        if opts.progress {
            eprintln!("{name}: flashed: {}", flash_report.describe());
        }
        reset_for_capture(&mut session, &elf).with_context(|| name.clone())?;
        let timeout_s = opts.timeout_s;
        let mut stop = |s: &LiveStatus| {
            s.state == Some(State::Safe)
                || s.in_run_ms().is_some_and(|t| t >= hold_ms)
                || s.wall_s >= timeout_s
        };
        let rec = record(&mut session, &elf, &opts.record, &mut stop)
            .with_context(|| format!("{name}: starting the capture"))?;
        drop(session);
        let raw = raw_path(out_dir, &name);
        let written = write_recording(&rec, elf_path, out_dir, &name);
        if let Some(e) = ended_error(&rec, &raw) {
            return Err(with_written(e.context(name.clone()), &written));
        }
        let last = rec
            .status
            .state
            .map_or("none (no record decoded)", State::name);
        if rec.status.state == Some(State::Safe) {
            let e = anyhow!(
                "{name}: the drive went to Safe ({}) at t = {:.3} s; {} (its events say what \
                 led there)",
                rec.status
                    .last_fault
                    .as_deref()
                    .unwrap_or("no fault event received"),
                f64::from(rec.status.t_ms.unwrap_or(0)) / 1000.0,
                kept(&rec, &raw)
            );
            return Err(with_written(e, &written));
        }
        if rec.status.in_run_ms().is_none_or(|t| t < hold_ms) {
            let e = anyhow!(
                "{name}: timed out after {timeout_s} s wall without {} s in Run; last state \
                 seen: {last} (check the motor, its supply and the sensor; a longer commissioning \
                 needs --timeout-s); {}",
                opts.hold_s,
                kept(&rec, &raw)
            );
            return Err(with_written(e, &written));
        }
        written.with_context(|| name.clone())?;
        boots.push(BootReport {
            name,
            raw_path: raw,
            flash: flash_report,
            losses: rec.status.losses,
            bytes: rec.raw.len() as u64,
            wall_s: rec.status.wall_s,
            calibration_loaded: rec.status.calibration_loaded,
            states: rec.states,
            events: rec.events,
        });
    }
    Ok(PowerUpReport { boots })
}

/// How [`attach_and_record`] runs.
#[derive(Clone, Debug, Default)]
pub struct AttachOptions {
    /// Reset the chip (after the ELF check) to capture from its boot.
    pub reset: bool,
    /// Wall seconds to record (None: until Ctrl-C or the probe is lost).
    pub duration_s: Option<f64>,
    pub record: RecordOptions,
}

/// The halt warning printed when attaching to a running drive.
pub const HALT_WARNING: &str = "attaching halts the core briefly (probe-rs halts, steps and \
     resumes it when the session opens and closes): TIM1 freezes and the bridge is off for \
     that moment; do not attach to a drive under load";

/// Record a running drive: check its firmware is `elf_path` ([`running_matches_elf`]),
/// reset it if asked, record until `duration_s`, Ctrl-C or the probe is lost, write
/// `name` in `out_dir`. Without a reset the capture starts mid-stream, after the
/// firmware's `mras-paths` line: the raw file is written but `rtt-log` cannot name the
/// coefficient columns (the error says to use `--reset`).
pub fn attach_and_record(
    session: &mut Session,
    elf_path: &Path,
    out_dir: &Path,
    name: &str,
    opts: &AttachOptions,
) -> Result<Recording> {
    let elf = read_elf(elf_path)?;
    running_matches_elf(session, &elf)?;
    if opts.reset {
        reset_for_capture(session, &elf)?;
    }
    let duration_s = opts.duration_s;
    let mut stop = |s: &LiveStatus| duration_s.is_some_and(|d| s.wall_s >= d);
    let rec = record(session, &elf, &opts.record, &mut stop)?;
    let raw = raw_path(out_dir, name);
    let written = write_recording(&rec, elf_path, out_dir, name);
    match ended_error(&rec, &raw) {
        // Ctrl-C is how an attach recording normally ends.
        Some(e) if rec.ended != Ended::Interrupted => Err(with_written(e, &written)),
        _ => {
            match (written, opts.reset) {
                (Err(e), false) => Err(e.context(
                    "attached mid-stream: without --reset the capture may start after the \
                     firmware's `mras-paths` line, which names the CSV's columns",
                )),
                (w, _) => w,
            }?;
            Ok(rec)
        }
    }
}

fn read_elf(elf_path: &Path) -> Result<Vec<u8>> {
    fs::read(elf_path).with_context(|| {
        format!(
            "{}: cannot read the firmware ELF (build it: `cargo xtask build-cross`, or pass --elf)",
            elf_path.display()
        )
    })
}

// ---------------------------------------------------------------------------------
// CLI
// ---------------------------------------------------------------------------------

#[derive(clap::Args, Clone, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub command: ProbeCommand,
}

/// Flags every `probe` subcommand takes.
#[derive(clap::Args, Clone, Debug)]
pub struct Common {
    /// The firmware ELF (default: this checkout's release build,
    /// target/thumbv7em-none-eabihf/release/drive-fw).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// The probe's serial number, when several are connected (`probe-rs list`).
    #[arg(long = "probe", value_name = "SERIAL")]
    pub probe: Option<String>,
    /// probe-rs's name of the chip.
    #[arg(long, default_value = DEFAULT_CHIP)]
    pub chip: String,
}

/// Flags of the recording subcommands.
#[derive(clap::Args, Clone, Debug)]
pub struct Output {
    /// Output directory (default: target/bench of the checkout).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Live status on stderr.
    #[arg(long, value_enum, default_value_t = StatusDisplay::Auto)]
    pub status: StatusDisplay,
}

#[derive(clap::Subcommand, Clone, Debug)]
pub enum ProbeCommand {
    /// Flash the ELF (only the sectors it occupies: the calibration survives) and verify.
    Flash {
        #[command(flatten)]
        common: Common,
        /// Reset the chip running afterwards.
        #[arg(long)]
        reset: bool,
    },
    /// Record a running drive's RTT stream (raw .defmt, CSV, events, plots) until Ctrl-C
    /// or --duration-s. Attaching halts the core briefly (probe-rs halts, steps and
    /// resumes it when the session opens and closes): TIM1 freezes and the bridge is off
    /// for that moment.
    Attach {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        output: Output,
        /// Wall seconds to record.
        #[arg(long)]
        duration_s: Option<f64>,
        /// Reset the chip after the firmware check, to capture from its boot (needed for
        /// the CSV: its columns are named by the firmware's first line).
        #[arg(long)]
        reset: bool,
        /// Output name (NAME.defmt, NAME.csv, ...).
        #[arg(long, default_value = "attach")]
        name: String,
    },
    /// The commissioning power-up and the reboot: flash, reset, record to Run and
    /// --hold-s more; reflash (the calibration pages survive), reset, record to Run with
    /// the stored calibration. Writes power-up-1.* and power-up-2.*.
    PowerUp {
        #[command(flatten)]
        common: Common,
        #[command(flatten)]
        output: Output,
        /// Firmware seconds to record once in Run.
        #[arg(long, default_value_t = 2.0)]
        hold_s: f64,
        /// Wall seconds a boot's recording (after its flash) may take to reach Run and
        /// hold.
        #[arg(long, default_value_t = 120.0)]
        timeout_s: f64,
    },
}

fn elf_of(c: &Common) -> PathBuf {
    c.elf.clone().unwrap_or_else(stream::release_elf)
}

fn out_of(o: &Output) -> PathBuf {
    o.out
        .clone()
        .unwrap_or_else(|| crate::checkout::target_dir().join("bench"))
}

fn open_session(c: &Common) -> Result<Session> {
    attach(list_and_select(c.probe.as_deref())?, &c.chip)
}

pub fn run(a: &Args) -> Result<()> {
    catch_ctrl_c();
    clear_interrupt();
    match &a.command {
        ProbeCommand::Flash { common, reset } => {
            let elf_path = elf_of(common);
            let elf = read_elf(&elf_path)?;
            let mut session = open_session(common)?;
            let report = flash(&mut session, &elf_path, true)?;
            println!("flashed {}: {}", elf_path.display(), report.describe());
            if *reset {
                reset_for_capture(&mut session, &elf)?;
                println!("reset: running");
            }
            Ok(())
        }
        ProbeCommand::Attach {
            common,
            output,
            duration_s,
            reset,
            name,
        } => {
            let elf_path = elf_of(common);
            let out = out_of(output);
            eprintln!("warning: {HALT_WARNING}");
            let mut session = open_session(common)?;
            let opts = AttachOptions {
                reset: *reset,
                duration_s: *duration_s,
                record: RecordOptions {
                    display: output.status,
                    ctrl_c: true,
                    ..RecordOptions::default()
                },
            };
            let rec = attach_and_record(&mut session, &elf_path, &out, name, &opts)?;
            println!(
                "recorded {} bytes in {:.1} s -> {}",
                rec.raw.len(),
                rec.status.wall_s,
                raw_path(&out, name).display()
            );
            Ok(())
        }
        ProbeCommand::PowerUp {
            common,
            output,
            hold_s,
            timeout_s,
        } => {
            let elf_path = elf_of(common);
            let out = out_of(output);
            let opts = PowerUpOptions {
                hold_s: *hold_s,
                timeout_s: *timeout_s,
                record: RecordOptions {
                    display: output.status,
                    ctrl_c: true,
                    ..RecordOptions::default()
                },
                progress: true,
            };
            let report = power_up(&mut || open_session(common), &elf_path, &out, &opts)?;
            print!("{}", power_up_summary(&report));
            if !report.calibration_loaded_on_reboot() {
                bail!(
                    "the reboot did not load a stored calibration (no `mras-loaded` event): \
                     see power-up-2's events in {}",
                    out.display()
                );
            }
            Ok(())
        }
    }
}

/// The report as text, a boot per paragraph.
pub fn power_up_summary(r: &PowerUpReport) -> String {
    let mut s = String::new();
    if r.boots.first().is_some_and(|b| b.calibration_loaded) {
        let _ = writeln!(
            s,
            "note: power-up-1 loaded a calibration already stored on the board: no \
             commissioning ran"
        );
    }
    for b in &r.boots {
        let _ = writeln!(s, "{} ({}):", b.name, b.raw_path.display());
        let _ = writeln!(s, "  flash: {}", b.flash.describe());
        let _ = writeln!(s, "  states: {}", b.state_sequence());
        let _ = writeln!(
            s,
            "  {} bytes in {:.1} s wall; losses: {}; calibration loaded at boot: {}",
            b.bytes,
            b.wall_s,
            b.losses.describe(),
            if b.calibration_loaded { "yes" } else { "no" }
        );
        for e in &b.events {
            let t = e.t_ms().map_or(0.0, |t| f64::from(t) / 1000.0);
            let _ = writeln!(s, "    {t:>9.3} s  {:<22} {}", e.kind, e.describe());
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use probe_rs::probe::stlink::StLinkFactory;

    fn probe(name: &str, serial: Option<&str>) -> DebugProbeInfo {
        let serial = serial.map(String::from);
        DebugProbeInfo::new(name, 0x0483, 0x374e, serial, &StLinkFactory, None, false)
    }

    fn err(r: Result<usize>) -> String {
        format!("{:#}", r.unwrap_err())
    }

    #[test]
    fn no_probe_says_what_to_check() {
        let e = err(choose_probe(&[], None));
        for what in ["no debug probe", "USB", "udev", "probe-rs list"] {
            assert!(e.contains(what), "{e}");
        }
        assert!(err(choose_probe(&[], Some("X"))).contains("no debug probe"));
    }

    #[test]
    fn one_probe_is_taken_several_need_a_serial() {
        let one = [probe("STLink V3", Some("003A"))];
        assert_eq!(choose_probe(&one, None).unwrap(), 0);
        let two = [probe("STLink V3", Some("003A")), probe("STLink V2", None)];
        let e = err(choose_probe(&two, None));
        for what in [
            "2 debug probes",
            "--probe SERIAL",
            "003A",
            "STLink V2 (serial none",
        ] {
            assert!(e.contains(what), "{e}");
        }
        assert_eq!(choose_probe(&two, Some("003A")).unwrap(), 0);
    }

    #[test]
    fn a_serial_not_found_lists_what_is_there() {
        let two = [
            probe("STLink V3", Some("003A")),
            probe("STLink V3", Some("0042")),
        ];
        let e = err(choose_probe(&two, Some("0099")));
        for what in ["`0099`", "003A", "0042"] {
            assert!(e.contains(what), "{e}");
        }
        assert_eq!(choose_probe(&two, Some("0042")).unwrap(), 1);
        let same = [probe("a", Some("7")), probe("b", Some("7"))];
        assert!(err(choose_probe(&same, Some("7"))).contains("share"));
    }

    #[test]
    fn only_dev_id_0x469_is_accepted_and_others_are_named() {
        // REV_ID in the high half does not matter.
        check_dev_id(0x2000_6469).unwrap();
        check_dev_id(0x469).unwrap();
        let e = |id| format!("{:#}", check_dev_id(id).unwrap_err());
        let g431 = e(0x2001_6468);
        assert!(
            g431.contains("STM32G431/G441") && g431.contains("0x468"),
            "{g431}"
        );
        assert!(g431.contains("STM32G474RE"), "{g431}");
        let g491 = e(0x1000_2479);
        assert!(
            g491.contains("STM32G491") && g491.contains("0x479"),
            "{g491}"
        );
        let other = e(0x1000_6415);
        assert!(
            other.contains("unknown part") && other.contains("0x415"),
            "{other}"
        );
        assert!(e(0).contains("no device ID"));
        assert!(e(u32::MAX).contains("no device ID"));
    }

    /// A flash image at 0x0800_0000 read like a probe would.
    fn reader(mem: &[u8]) -> impl FnMut(u64, &mut [u8]) -> Result<()> + '_ {
        move |addr, buf| {
            let off = addr
                .checked_sub(0x0800_0000)
                .ok_or_else(|| anyhow!("unmapped {addr:#x}"))? as usize;
            let src = mem
                .get(off..off + buf.len())
                .ok_or_else(|| anyhow!("unmapped {addr:#x}"))?;
            buf.copy_from_slice(src);
            Ok(())
        }
    }

    #[test]
    fn flash_is_compared_segment_by_segment_and_the_first_difference_named() {
        let mut mem: Vec<u8> = (0..8192u32).map(|i| (i * 7 % 251) as u8).collect();
        // Two segments out of order (the vector table and text, then .data's image);
        // the gap between them is not the ELF's.
        let segs = [
            LoadSegment {
                paddr: 0x0800_1800,
                data: mem[0x1800..0x1900].to_vec(),
            },
            LoadSegment {
                paddr: 0x0800_0000,
                data: mem[..3000].to_vec(),
            },
        ];
        mem[3500] ^= 0xFF;
        assert_eq!(first_difference(&segs, &mut reader(&mem)).unwrap(), None);
        mem[0x1805] ^= 1;
        mem[2500] ^= 0x10;
        let d = first_difference(&segs, &mut reader(&mem)).unwrap().unwrap();
        assert_eq!(
            d,
            Difference {
                addr: 0x0800_0000 + 2500,
                expected: mem[2500] ^ 0x10,
                found: mem[2500],
            }
        );
        mem[2500] ^= 0x10;
        let d = first_difference(&segs, &mut reader(&mem)).unwrap().unwrap();
        assert_eq!(d.addr, 0x0800_1805);
        // A segment beyond the memory: the read error is named, not a panic.
        let beyond = [LoadSegment {
            paddr: 0x0800_3000,
            data: vec![0; 16],
        }];
        let e = first_difference(&beyond, &mut reader(&mem[..100])).unwrap_err();
        assert!(format!("{e:#}").contains("0x08003000"), "{e:#}");
    }

    #[test]
    fn bad_elves_are_errors() {
        assert!(load_segments(b"not an elf").is_err());
        assert!(rtt_address(b"not an elf").is_err());
    }
}
