//! The host side of RTT (SEGGER's protocol, as probe-rs reads it): the up-buffer of
//! channel 0 read from emulated RAM through the control block `_SEGGER_RTT`.

use crate::periph::ticks;

/// Host polling period (probe-rs polls every few milliseconds).
pub const POLL_S: f64 = 1.0e-3;

#[derive(Debug, Default)]
pub struct Rtt {
    pub block: Option<u32>,
    /// Raw defmt bytes received, with the time (ticks) of each read.
    pub bytes: Vec<u8>,
    pub next_poll: u64,
    /// The host reads (false: a detached or stalled host; the buffer fills).
    pub reading: bool,
    pub reads: u64,
    /// Consume (the default: the emulator is the host, it advances RdOff) or Observe
    /// (a probe's RTT client consumes; the emulator only copies what the firmware
    /// wrote, never writing RdOff).
    pub mode: RttMode,
    /// Observe mode: the write offset seen at the last poll.
    pub seen_wr: Option<u32>,
    /// Where in `bytes` each boot's stream begins (a reset re-initialises the buffer).
    pub boot_starts: Vec<usize>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RttMode {
    #[default]
    Consume,
    Observe,
}

/// The up-buffer descriptor of channel 0: offset in the control block (16-byte id, two
/// counts).
pub const UP0: u32 = 24;

impl Rtt {
    pub fn new(block: Option<u32>) -> Self {
        Self {
            block,
            reading: true,
            ..Self::default()
        }
    }

    pub fn schedule(&mut self, now: u64) {
        self.next_poll = now + ticks(POLL_S);
    }
}

impl Rtt {
    /// A reset: the firmware writes its control block again, from offset 0.
    pub fn reset(&mut self) {
        self.seen_wr = None;
        if self.boot_starts.last() != Some(&self.bytes.len()) {
            self.boot_starts.push(self.bytes.len());
        }
    }

    /// The bytes of each boot that wrote any.
    pub fn boots(&self) -> Vec<&[u8]> {
        let mut cuts = vec![0];
        cuts.extend(self.boot_starts.iter().copied());
        cuts.push(self.bytes.len());
        cuts.windows(2)
            .filter(|w| w[1] > w[0])
            .map(|w| &self.bytes[w[0]..w[1]])
            .collect()
    }
}
