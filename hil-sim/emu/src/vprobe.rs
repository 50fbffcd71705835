//! A debug probe wired to the emulated board: probe-rs's own attach, flash algorithms and
//! RTT reader run against the emulated STM32G474 through a library-defined probe.
//!
//! Two halves:
//! - [`EmuThread`]: the machine on its own thread. Unicorn is not `Send`, probe-rs's
//!   probes must be, so the port is built on the thread from a `Send` factory and reached
//!   through a channel. Between requests the thread lets emulated time pass at the real
//!   board's pace at most (probe-rs's timeouts are wall-clock: a board that ran faster
//!   than real time would meet deadlines a real one misses, and the plant would drift
//!   from what the host sees).
//! - [`VirtualProbe`]: `probe_rs::probe::DebugProbe` plus the ARM interface probe-rs's
//!   high-level probes (ST-Link, Black Magic) offer: whole MEM-AP transfers, no DP/AP
//!   register emulation.

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, TryRecvError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use probe_rs::architecture::arm::ap::CSW;
use probe_rs::architecture::arm::dp::{DpAddress, DpRegisterAddress};
use probe_rs::architecture::arm::memory::ArmMemoryInterface;
use probe_rs::architecture::arm::sequences::ArmDebugSequence;
use probe_rs::architecture::arm::{
    ArmDebugInterface, ArmError, DapAccess, DapError, DapProbe, FullyQualifiedApAddress,
    SwdSequence, SwoAccess, SwoConfig,
};
use probe_rs::probe::{DebugProbe, DebugProbeError, Probe, WireProtocol};
use probe_rs::MemoryInterface;

use crate::debug::{ApFault, DebugPort};

/// The core clock: the port's ticks.
const TICK_HZ: u64 = 170_000_000;

/// The longest emulated slice between two looks at the channel: a request waits at most
/// one slice (about 3 ms of wall time with the emulator ~3x slower than the board).
const SLICE_CAP: Duration = Duration::from_millis(1);
/// Below this much credit a slice costs more in call overhead than it runs; the thread
/// waits on the channel instead of spinning.
const MIN_SLICE: Duration = Duration::from_micros(100);
/// After a request, keep listening this long: probe-rs's operations are bursts of
/// dependent accesses (write DCRSR, poll DHCSR, read DCRDR), each waiting for the last.
const BURST_GAP: Duration = Duration::from_micros(200);
/// ...but never listen longer than this without running the machine: a probe polling
/// without pause (probe-rs waiting for the reset to end) still sees the machine move.
const MAX_LISTEN: Duration = Duration::from_millis(2);

/// How emulated time relates to wall time on the thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Pacing {
    /// No faster than the real board: each slice runs at most the wall time elapsed since
    /// the previous one, capped at [`SLICE_CAP`]; time the emulator falls behind is not
    /// made up (no catch-up credit).
    #[default]
    Wall,
    /// As fast as the emulator goes, a capped slice between looks at the channel (tests
    /// against a fake port).
    Free,
}

type Job<P> = Box<dyn FnOnce(&mut P) + Send>;

enum Msg<P> {
    Job(Job<P>),
    Finish(Box<dyn FnOnce(P) + Send>),
}

/// What the thread shares with its handles and probes.
struct Shared {
    /// Set by [`EmuThread`]'s drop: the thread ends at its next look at the channel.
    stop: AtomicBool,
    /// Why the machine stopped running (an `advance` error, a panic), if it did.
    stopped: Mutex<Option<String>>,
}

impl Shared {
    fn stopped(&self) -> Option<String> {
        self.stopped.lock().map(|s| s.clone()).unwrap_or_else(|_| {
            Some("the emulator's thread panicked while reporting a fault".into())
        })
    }

    fn set_stopped(&self, why: String) {
        if let Ok(mut s) = self.stopped.lock() {
            s.get_or_insert(why);
        }
    }
}

/// The emulated board on its own thread. `P` is built on the thread and never leaves it
/// except through [`EmuThread::finish`].
pub struct EmuThread<P: DebugPort + 'static> {
    tx: Sender<Msg<P>>,
    shared: Arc<Shared>,
    unplugged: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    serial: String,
}

impl<P: DebugPort + 'static> EmuThread<P> {
    /// Spawns the thread, builds the port there with `factory` and starts time passing.
    /// Fails if the factory does.
    pub fn spawn<F>(factory: F, pacing: Pacing) -> Result<Self>
    where
        F: FnOnce() -> Result<P> + Send + 'static,
    {
        let (tx, rx) = mpsc::channel::<Msg<P>>();
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            stopped: Mutex::new(None),
        });
        let sh = shared.clone();
        let thread = std::thread::Builder::new()
            .name("drive-emu".into())
            .spawn(move || {
                let port = match factory() {
                    Ok(p) => {
                        let _ = ready_tx.send(Ok(()));
                        p
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(format!("{e:#}")));
                        return;
                    }
                };
                // A panic of the port (or of a `with` closure) ends the machine; say so to
                // the probes instead of leaving them a bare disconnected channel.
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    serve(port, rx, pacing, &sh)
                }));
                if let Err(e) = r {
                    sh.set_stopped(format!(
                        "the emulator's thread panicked: {}",
                        panic_message(Err(e))
                    ));
                }
            })
            .context("spawning the emulator's thread")?;
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                let _ = thread.join();
                return Err(anyhow!("building the emulated board: {e}"));
            }
            Err(_) => {
                let why = panic_message(thread.join());
                return Err(anyhow!("the emulator's thread died while starting: {why}"));
            }
        }
        static SERIAL: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let serial = format!(
            "EMU{:05}{:03}",
            std::process::id() % 100_000,
            SERIAL.fetch_add(1, Ordering::Relaxed) % 1000
        );
        Ok(Self {
            tx,
            shared,
            unplugged: Arc::new(AtomicBool::new(false)),
            thread: Some(thread),
            serial,
        })
    }

    /// Runs `f` on the machine between two slices and returns its result: inspect or
    /// adjust the emulator mid-run. Works after the machine stopped (to read why).
    pub fn with<T, F>(&self, f: F) -> Result<T>
    where
        T: Send + 'static,
        F: FnOnce(&mut P) -> T + Send + 'static,
    {
        call(&self.tx, f).map_err(|()| self.gone())
    }

    /// Stops the thread and hands the port to `f` (results, statistics). Probes made by
    /// [`EmuThread::probe`] fail from then on.
    pub fn finish<R, F>(mut self, f: F) -> Result<R>
    where
        R: Send + 'static,
        F: FnOnce(P) -> R + Send + 'static,
    {
        let (rtx, rrx) = mpsc::channel();
        let sent = self.tx.send(Msg::Finish(Box::new(move |p| {
            let _ = rtx.send(f(p));
        })));
        // A message that was not sent still holds the reply's sender: waiting on it then
        // would never end.
        let got = sent.ok().and_then(|()| rrx.recv().ok());
        let joined = self.thread.take().map(JoinHandle::join);
        match got {
            Some(r) => Ok(r),
            None => match joined {
                Some(Err(e)) => Err(anyhow!(
                    "the emulator's thread is gone: {}",
                    panic_message(Err(e))
                )),
                _ => Err(self.gone()),
            },
        }
    }

    /// A probe plugged into the board. Call it again for each session (flash, then attach
    /// again later): probe-rs consumes a `Probe` per session.
    pub fn probe(&self) -> Probe {
        Probe::from_specific_probe(Box::new(self.virtual_probe()))
    }

    /// The probe itself (what [`EmuThread::probe`] wraps).
    pub fn virtual_probe(&self) -> VirtualProbe {
        VirtualProbe {
            link: Arc::new(Link {
                tx: self.tx.clone(),
                shared: self.shared.clone(),
            }),
            unplugged: self.unplugged.clone(),
            serial: self.serial.clone(),
            name: format!("drive-emu virtual probe (serial {})", self.serial),
            speed_khz: 4000,
            protocol: WireProtocol::Swd,
            reset_asserted: false,
        }
    }

    /// Pulls the probe's cable: every access of every probe of this board fails from now
    /// on with an error probe-rs reports as a probe gone from the bus ([`is_unplugged`]).
    /// The board keeps running.
    pub fn unplug(&self) {
        self.unplugged.store(true, Ordering::SeqCst);
    }

    /// Plugs it back (a new session attaches again).
    pub fn replug(&self) {
        self.unplugged.store(false, Ordering::SeqCst);
    }

    /// The serial number the probes report.
    pub fn serial(&self) -> &str {
        &self.serial
    }

    /// Why the machine stopped running, if it did (an error of the port's `advance`).
    pub fn stopped(&self) -> Option<String> {
        self.shared.stopped()
    }

    fn gone(&self) -> anyhow::Error {
        anyhow!(
            "the emulator's thread is gone{}",
            self.shared
                .stopped()
                .map(|s| format!(": {s}"))
                .unwrap_or_default()
        )
    }
}

impl<P: DebugPort + 'static> Drop for EmuThread<P> {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn panic_message(r: std::thread::Result<()>) -> String {
    match r {
        Ok(()) => "it ended".into(),
        Err(e) => e
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "it panicked".into()),
    }
}

/// Sends `f` to the thread and waits for its result; `Err` if the thread is gone (the
/// reply's sender is dropped with the job when the thread ends or panics).
fn call<P, T, F>(tx: &Sender<Msg<P>>, f: F) -> Result<T, ()>
where
    T: Send + 'static,
    F: FnOnce(&mut P) -> T + Send + 'static,
{
    let (rtx, rrx) = mpsc::channel();
    tx.send(Msg::Job(Box::new(move |p: &mut P| {
        let _ = rtx.send(f(p));
    })))
    .map_err(|_| ())?;
    rrx.recv().map_err(|_| ())
}

fn dur_ticks(d: Duration) -> u64 {
    (d.as_nanos() * TICK_HZ as u128 / 1_000_000_000) as u64
}

/// The thread's loop: serve requests, let time pass, until told to stop.
fn serve<P: DebugPort>(mut port: P, rx: Receiver<Msg<P>>, pacing: Pacing, shared: &Shared) {
    let mut last = Instant::now();
    let mut running = true;
    loop {
        if shared.stop.load(Ordering::SeqCst) {
            return;
        }
        let listen_from = Instant::now();
        let mut listen_until = match (pacing, running) {
            (Pacing::Wall, true) => last + MIN_SLICE,
            (Pacing::Free, true) => listen_from,
            // A stopped machine only answers: wait in slices to see `stop`.
            (_, false) => listen_from + Duration::from_millis(50),
        };
        loop {
            let now = Instant::now();
            let msg = if now >= listen_until {
                match rx.try_recv() {
                    Ok(m) => Some(m),
                    Err(TryRecvError::Empty) => None,
                    Err(TryRecvError::Disconnected) => return,
                }
            } else {
                match rx.recv_timeout(listen_until - now) {
                    Ok(m) => Some(m),
                    Err(RecvTimeoutError::Timeout) => None,
                    Err(RecvTimeoutError::Disconnected) => return,
                }
            };
            match msg {
                Some(Msg::Job(f)) => {
                    f(&mut port);
                    let cap = listen_from.max(last) + MAX_LISTEN;
                    listen_until = listen_until.max((Instant::now() + BURST_GAP).min(cap));
                }
                Some(Msg::Finish(f)) => {
                    f(port);
                    return;
                }
                None => break,
            }
            if shared.stop.load(Ordering::SeqCst) {
                return;
            }
        }
        if !running {
            continue;
        }
        let now = Instant::now();
        let slice = match pacing {
            Pacing::Wall => now.saturating_duration_since(last).min(SLICE_CAP),
            Pacing::Free => SLICE_CAP,
        };
        last = now;
        if let Err(e) = port.advance(dur_ticks(slice)) {
            shared.set_stopped(format!("the emulated board stopped: {e:#}"));
            running = false;
        }
    }
}

/// Marks an access refused because the probe was unplugged ([`EmuThread::unplug`]); it is
/// the payload of the `DebugProbeError::Usb` a USB probe's driver reports when its device
/// vanishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unplugged;

impl std::fmt::Display for Unplugged {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the drive-emu virtual probe was unplugged")
    }
}

impl std::error::Error for Unplugged {}

/// Whether `err` (any probe-rs error, or an `anyhow` chain holding one) comes from an
/// unplugged virtual probe.
pub fn is_unplugged(err: &(dyn std::error::Error + 'static)) -> bool {
    let mut e = Some(err);
    while let Some(x) = e {
        if x.is::<Unplugged>() {
            return true;
        }
        if let Some(io) = x.downcast_ref::<std::io::Error>() {
            if io.get_ref().is_some_and(|i| i.is::<Unplugged>()) {
                return true;
            }
        }
        e = x.source();
    }
    false
}

fn unplugged_error() -> DebugProbeError {
    DebugProbeError::Usb(std::io::Error::new(
        std::io::ErrorKind::NotConnected,
        Unplugged,
    ))
}

/// The probe's side of the channel, without the port's type.
trait Port: Send + Sync {
    fn read(&self, addr: u32, width: u8, len: usize) -> Result<Vec<u8>, LinkError>;
    fn write(&self, addr: u32, width: u8, data: Vec<u8>) -> Result<(), LinkError>;
    fn pin_reset(&self) -> Result<(), LinkError>;
}

enum LinkError {
    Fault(ApFault),
    Gone(String),
}

struct Link<P: DebugPort + 'static> {
    tx: Sender<Msg<P>>,
    shared: Arc<Shared>,
}

impl<P: DebugPort + 'static> Link<P> {
    fn run<T, F>(&self, f: F) -> Result<T, LinkError>
    where
        T: Send + 'static,
        F: FnOnce(&mut P) -> T + Send + 'static,
    {
        // A board that no longer runs would answer forever with the same state; probe-rs
        // would then time out waiting for a halt. Say why instead.
        if let Some(why) = self.shared.stopped() {
            return Err(LinkError::Gone(why));
        }
        call(&self.tx, f).map_err(|()| {
            LinkError::Gone(
                self.shared
                    .stopped()
                    .unwrap_or_else(|| "the emulator's thread has ended".into()),
            )
        })
    }
}

impl<P: DebugPort + 'static> Port for Link<P> {
    fn read(&self, addr: u32, width: u8, len: usize) -> Result<Vec<u8>, LinkError> {
        self.run(move |p| {
            let mut buf = vec![0; len];
            p.read(addr, width, &mut buf).map(|()| buf)
        })?
        .map_err(LinkError::Fault)
    }

    fn write(&self, addr: u32, width: u8, data: Vec<u8>) -> Result<(), LinkError> {
        self.run(move |p| p.write(addr, width, &data))?
            .map_err(LinkError::Fault)
    }

    fn pin_reset(&self) -> Result<(), LinkError> {
        self.run(|p| p.pin_reset())
    }
}

/// A debug probe on the emulated board's SWD port. Made by [`EmuThread::probe`]; every
/// probe of one board shares its channel and its unplug switch.
pub struct VirtualProbe {
    link: Arc<dyn Port>,
    unplugged: Arc<AtomicBool>,
    serial: String,
    name: String,
    speed_khz: u32,
    protocol: WireProtocol,
    reset_asserted: bool,
}

impl std::fmt::Debug for VirtualProbe {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VirtualProbe")
            .field("serial", &self.serial)
            .field("unplugged", &self.unplugged.load(Ordering::Relaxed))
            .finish_non_exhaustive()
    }
}

impl VirtualProbe {
    fn check(&self) -> Result<(), DebugProbeError> {
        if self.unplugged.load(Ordering::SeqCst) {
            Err(unplugged_error())
        } else {
            Ok(())
        }
    }

    fn arm_err(e: LinkError) -> ArmError {
        match e {
            // A bus error: the MEM-AP answers the transfer with FAULT (the transfer's
            // address is in the error probe-rs wraps around it).
            LinkError::Fault(_) => ArmError::Dap(DapError::FaultResponse),
            LinkError::Gone(why) => ArmError::Probe(DebugProbeError::Other(why)),
        }
    }

    fn read_bytes(&self, addr: u64, width: u8, len: usize) -> Result<Vec<u8>, ArmError> {
        self.check()?;
        let a = addr32(addr, len)?;
        if !a.is_multiple_of(width as u32) {
            return Err(ArmError::alignment_error(addr, width as usize));
        }
        if len == 0 {
            return Ok(Vec::new());
        }
        self.link.read(a, width, len).map_err(Self::arm_err)
    }

    fn write_bytes(&self, addr: u64, width: u8, data: Vec<u8>) -> Result<(), ArmError> {
        self.check()?;
        let a = addr32(addr, data.len())?;
        if !a.is_multiple_of(width as u32) {
            return Err(ArmError::alignment_error(addr, width as usize));
        }
        if data.is_empty() {
            return Ok(());
        }
        self.link.write(a, width, data).map_err(Self::arm_err)
    }

    fn pulse_reset(&self) -> Result<(), DebugProbeError> {
        self.check()?;
        self.link.pin_reset().map_err(|e| match e {
            LinkError::Fault(f) => DebugProbeError::Other(f.to_string()),
            LinkError::Gone(why) => DebugProbeError::Other(why),
        })
    }
}

fn addr32(addr: u64, len: usize) -> Result<u32, ArmError> {
    if addr.checked_add(len as u64).is_none_or(|end| end > 1 << 32) {
        return Err(ArmError::AddressOutOf32BitAddressSpace);
    }
    Ok(addr as u32)
}

impl DebugProbe for VirtualProbe {
    fn get_name(&self) -> &str {
        &self.name
    }

    fn speed_khz(&self) -> u32 {
        self.speed_khz
    }

    fn set_speed(&mut self, speed_khz: u32) -> Result<u32, DebugProbeError> {
        self.speed_khz = speed_khz;
        Ok(speed_khz)
    }

    fn attach(&mut self) -> Result<(), DebugProbeError> {
        self.check()
    }

    fn detach(&mut self) -> Result<(), probe_rs::Error> {
        // Leaving works even unplugged: a session's drop must not fail twice.
        Ok(())
    }

    fn target_reset(&mut self) -> Result<(), DebugProbeError> {
        self.pulse_reset()
    }

    // The port has a pulse, not a level: the chip restarts when NRST is released, so the
    // pulse goes with the release.
    fn target_reset_assert(&mut self) -> Result<(), DebugProbeError> {
        self.check()?;
        self.reset_asserted = true;
        Ok(())
    }

    fn target_reset_deassert(&mut self) -> Result<(), DebugProbeError> {
        if std::mem::take(&mut self.reset_asserted) {
            self.pulse_reset()
        } else {
            self.check()
        }
    }

    fn select_protocol(&mut self, protocol: WireProtocol) -> Result<(), DebugProbeError> {
        match protocol {
            WireProtocol::Swd => {
                self.protocol = protocol;
                Ok(())
            }
            other => Err(DebugProbeError::UnsupportedProtocol(other)),
        }
    }

    fn active_protocol(&self) -> Option<WireProtocol> {
        Some(self.protocol)
    }

    fn has_arm_interface(&self) -> bool {
        true
    }

    fn try_get_arm_debug_interface<'probe>(
        self: Box<Self>,
        _sequence: Arc<dyn ArmDebugSequence>,
    ) -> Result<Box<dyn ArmDebugInterface + 'probe>, (Box<dyn DebugProbe>, ArmError)> {
        Ok(Box::new(VirtualArm {
            probe: self,
            dp: None,
        }))
    }

    fn into_probe(self: Box<Self>) -> Box<dyn DebugProbe> {
        self
    }
}

/// The ARM side of the probe: one MEM-AP (AP 0, the Cortex-M4's AHB-AP) on the default DP.
#[derive(Debug)]
struct VirtualArm {
    probe: Box<VirtualProbe>,
    dp: Option<DpAddress>,
}

fn not_here(function_name: &'static str) -> ArmError {
    ArmError::Probe(DebugProbeError::NotImplemented { function_name })
}

impl SwdSequence for VirtualArm {
    fn swj_sequence(&mut self, _bit_len: u8, _bits: u64) -> Result<(), DebugProbeError> {
        // Line resets and JTAG-to-SWD switches: nothing to switch on this wire.
        self.probe.check()
    }

    fn swj_pins(
        &mut self,
        _pin_out: u32,
        _pin_select: u32,
        _pin_wait: u32,
    ) -> Result<u32, DebugProbeError> {
        Err(DebugProbeError::CommandNotSupportedByProbe {
            command_name: "swj_pins",
        })
    }
}

impl SwoAccess for VirtualArm {
    fn enable_swo(&mut self, _config: &SwoConfig) -> Result<(), ArmError> {
        Err(not_here("enable_swo"))
    }

    fn disable_swo(&mut self) -> Result<(), ArmError> {
        Err(not_here("disable_swo"))
    }

    fn read_swo_timeout(&mut self, _timeout: Duration) -> Result<Vec<u8>, ArmError> {
        Err(not_here("read_swo_timeout"))
    }
}

// Raw DP/AP registers are not emulated: probe-rs's high-level route (the one ST-Link
// takes) goes through `memory_interface` only.
impl DapAccess for VirtualArm {
    fn read_raw_dp_register(
        &mut self,
        _dp: DpAddress,
        _addr: DpRegisterAddress,
    ) -> Result<u32, ArmError> {
        Err(not_here("read_raw_dp_register"))
    }

    fn write_raw_dp_register(
        &mut self,
        _dp: DpAddress,
        _addr: DpRegisterAddress,
        _value: u32,
    ) -> Result<(), ArmError> {
        Err(not_here("write_raw_dp_register"))
    }

    fn read_raw_ap_register(
        &mut self,
        _ap: &FullyQualifiedApAddress,
        _addr: u64,
    ) -> Result<u32, ArmError> {
        Err(not_here("read_raw_ap_register"))
    }

    fn write_raw_ap_register(
        &mut self,
        _ap: &FullyQualifiedApAddress,
        _addr: u64,
        _value: u32,
    ) -> Result<(), ArmError> {
        Err(not_here("write_raw_ap_register"))
    }

    fn try_dap_probe(&self) -> Option<&dyn DapProbe> {
        None
    }

    fn try_dap_probe_mut(&mut self) -> Option<&mut dyn DapProbe> {
        None
    }
}

impl ArmDebugInterface for VirtualArm {
    fn reinitialize(&mut self) -> Result<(), ArmError> {
        Ok(self.probe.check()?)
    }

    fn access_ports(
        &mut self,
        dp: DpAddress,
    ) -> Result<BTreeSet<FullyQualifiedApAddress>, ArmError> {
        self.probe.check()?;
        Ok(BTreeSet::from([FullyQualifiedApAddress::v1_with_dp(dp, 0)]))
    }

    fn close(self: Box<Self>) -> Probe {
        Probe::from_specific_probe(self.probe)
    }

    fn select_debug_port(&mut self, dp: DpAddress) -> Result<(), ArmError> {
        self.probe.check()?;
        self.dp = Some(dp);
        Ok(())
    }

    fn current_debug_port(&self) -> Option<DpAddress> {
        self.dp
    }

    fn memory_interface(
        &mut self,
        access_port: &FullyQualifiedApAddress,
    ) -> Result<Box<dyn ArmMemoryInterface + '_>, ArmError> {
        self.probe.check()?;
        Ok(Box::new(VirtualMem {
            ap: access_port.clone(),
            arm: self,
        }))
    }
}

/// The MEM-AP's transfers: each call is one request to the thread, whole blocks at once.
struct VirtualMem<'a> {
    ap: FullyQualifiedApAddress,
    arm: &'a mut VirtualArm,
}

fn from_le<const N: usize, T>(bytes: &[u8], out: &mut [T], f: fn([u8; N]) -> T) {
    for (o, c) in out.iter_mut().zip(bytes.chunks_exact(N)) {
        let mut a = [0; N];
        a.copy_from_slice(c);
        *o = f(a);
    }
}

impl MemoryInterface<ArmError> for VirtualMem<'_> {
    fn supports_native_64bit_access(&mut self) -> bool {
        // The Cortex-M4's AHB-AP is 32 bits wide.
        false
    }

    fn read_64(&mut self, address: u64, data: &mut [u64]) -> Result<(), ArmError> {
        let b = self.arm.probe.read_bytes(address, 4, data.len() * 8)?;
        from_le(&b, data, u64::from_le_bytes);
        Ok(())
    }

    fn read_32(&mut self, address: u64, data: &mut [u32]) -> Result<(), ArmError> {
        let b = self.arm.probe.read_bytes(address, 4, data.len() * 4)?;
        from_le(&b, data, u32::from_le_bytes);
        Ok(())
    }

    fn read_16(&mut self, address: u64, data: &mut [u16]) -> Result<(), ArmError> {
        let b = self.arm.probe.read_bytes(address, 2, data.len() * 2)?;
        from_le(&b, data, u16::from_le_bytes);
        Ok(())
    }

    fn read_8(&mut self, address: u64, data: &mut [u8]) -> Result<(), ArmError> {
        let b = self.arm.probe.read_bytes(address, 1, data.len())?;
        data.copy_from_slice(&b);
        Ok(())
    }

    fn read(&mut self, address: u64, data: &mut [u8]) -> Result<(), ArmError> {
        // Words for the aligned middle, bytes at the edges: three requests at most.
        let head = ((4 - (address % 4) as usize) % 4).min(data.len());
        let words = (data.len() - head) / 4 * 4;
        let (h, rest) = data.split_at_mut(head);
        let (w, t) = rest.split_at_mut(words);
        self.read_8(address, h)?;
        if !w.is_empty() {
            let b = self.arm.probe.read_bytes(address + head as u64, 4, words)?;
            w.copy_from_slice(&b);
        }
        self.read_8(address + (head + words) as u64, t)
    }

    fn write_64(&mut self, address: u64, data: &[u64]) -> Result<(), ArmError> {
        let b = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.arm.probe.write_bytes(address, 4, b)
    }

    fn write_32(&mut self, address: u64, data: &[u32]) -> Result<(), ArmError> {
        let b = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.arm.probe.write_bytes(address, 4, b)
    }

    fn write_16(&mut self, address: u64, data: &[u16]) -> Result<(), ArmError> {
        let b = data.iter().flat_map(|v| v.to_le_bytes()).collect();
        self.arm.probe.write_bytes(address, 2, b)
    }

    fn write_8(&mut self, address: u64, data: &[u8]) -> Result<(), ArmError> {
        self.arm.probe.write_bytes(address, 1, data.to_vec())
    }

    fn write(&mut self, address: u64, data: &[u8]) -> Result<(), ArmError> {
        let head = ((4 - (address % 4) as usize) % 4).min(data.len());
        let words = (data.len() - head) / 4 * 4;
        let (h, rest) = data.split_at(head);
        let (w, t) = rest.split_at(words);
        self.write_8(address, h)?;
        if !w.is_empty() {
            self.arm
                .probe
                .write_bytes(address + head as u64, 4, w.to_vec())?;
        }
        self.write_8(address + (head + words) as u64, t)
    }

    fn supports_8bit_transfers(&self) -> Result<bool, ArmError> {
        Ok(true)
    }

    fn flush(&mut self) -> Result<(), ArmError> {
        // Every transfer is answered before the call returns: nothing is queued.
        Ok(self.arm.probe.check()?)
    }
}

impl ArmMemoryInterface for VirtualMem<'_> {
    fn fully_qualified_address(&self) -> FullyQualifiedApAddress {
        self.ap.clone()
    }

    fn base_address(&mut self) -> Result<u64, ArmError> {
        // The Cortex-M4's ROM table (the AHB-AP's BASE register).
        Ok(0xE00F_F000)
    }

    fn get_arm_debug_interface(&mut self) -> Result<&mut dyn ArmDebugInterface, DebugProbeError> {
        Ok(self.arm)
    }

    fn generic_status(&mut self) -> Result<CSW, ArmError> {
        Err(not_here("generic_status"))
    }
}
