//! The Cortex-M4's exception model (ARMv7-M ARM B1.5), which Unicorn does not have:
//! priorities, pending and active state, the execution priority with PRIMASK and
//! BASEPRI, and the NVIC/SCB registers that hold them.

/// Exception numbers (ARMv7-M B1.5.2).
pub const NMI: u16 = 2;
pub const HARD_FAULT: u16 = 3;
pub const PENDSV: u16 = 14;
pub const SYSTICK: u16 = 15;
/// External interrupt `irq` is exception 16 + irq.
pub const fn irq(n: u16) -> u16 {
    16 + n
}

/// Priority of an exception no running code masks (thread mode, nothing active).
pub const THREAD_PRIORITY: i16 = 256;

#[derive(Clone, Debug)]
pub struct Nvic {
    pub enabled: [u32; 8],
    pending_irq: [u32; 8],
    /// NVIC_IPRn bytes (external interrupts).
    pub ipr: [u8; 240],
    /// SHPR1-3 bytes: exceptions 4..=15.
    pub shpr: [u8; 12],
    pub nmi_pending: bool,
    pub hard_fault_pending: bool,
    pub pendsv_pending: bool,
    pub systick_pending: bool,
    /// Active exceptions, innermost last (nesting).
    pub active: Vec<u16>,
    /// AIRCR.PRIGROUP: the split of a priority into group and subpriority.
    pub prigroup: u8,
}

impl Default for Nvic {
    fn default() -> Self {
        Self {
            enabled: [0; 8],
            pending_irq: [0; 8],
            ipr: [0; 240],
            shpr: [0; 12],
            nmi_pending: false,
            hard_fault_pending: false,
            pendsv_pending: false,
            systick_pending: false,
            active: Vec::new(),
            prigroup: 0,
        }
    }
}

impl Nvic {
    /// Priority of exception `n` (lower is more urgent).
    pub fn priority(&self, n: u16) -> i16 {
        match n {
            1 => -3,
            NMI => -2,
            HARD_FAULT => -1,
            4..=15 => self.group(self.shpr[(n - 4) as usize]),
            _ => self.group(self.ipr[(n - 16) as usize]),
        }
    }

    /// The group priority: the bits above PRIGROUP preempt (B1.5.4).
    fn group(&self, p: u8) -> i16 {
        let sub_bits = (self.prigroup as u32 + 1).min(8);
        ((p as u32 >> sub_bits) << sub_bits) as i16
    }

    pub fn pend_irq(&mut self, n: u16) {
        self.pending_irq[(n / 32) as usize] |= 1 << (n % 32);
    }

    pub fn unpend_irq(&mut self, n: u16) {
        self.pending_irq[(n / 32) as usize] &= !(1 << (n % 32));
    }

    pub fn irq_pending(&self, n: u16) -> bool {
        self.pending_irq[(n / 32) as usize] & (1 << (n % 32)) != 0
    }

    pub fn pending_word(&self, i: usize) -> u32 {
        self.pending_irq[i]
    }

    pub fn set_pending_word(&mut self, i: usize, set: u32, clear: u32) {
        self.pending_irq[i] = (self.pending_irq[i] | set) & !clear;
    }

    pub fn any_pending(&self) -> bool {
        self.nmi_pending
            || self.hard_fault_pending
            || self.pendsv_pending
            || self.systick_pending
            || self
                .pending_irq
                .iter()
                .zip(&self.enabled)
                .any(|(p, e)| p & e != 0)
    }

    /// The most urgent pending exception that is enabled: (number, priority). Equal
    /// priorities go to the lower exception number (B1.5.4).
    pub fn most_urgent_pending(&self) -> Option<(u16, i16)> {
        let mut best: Option<(u16, i16)> = None;
        let mut consider = |n: u16, prio: i16| {
            if best.is_none_or(|(_, p)| prio < p) {
                best = Some((n, prio));
            }
        };
        if self.nmi_pending {
            consider(NMI, -2);
        }
        if self.hard_fault_pending {
            consider(HARD_FAULT, -1);
        }
        if self.pendsv_pending {
            consider(PENDSV, self.priority(PENDSV));
        }
        if self.systick_pending {
            consider(SYSTICK, self.priority(SYSTICK));
        }
        for w in 0..8 {
            let mut bits = self.pending_irq[w] & self.enabled[w];
            while bits != 0 {
                let b = bits.trailing_zeros() as u16;
                bits &= bits - 1;
                let n = irq(w as u16 * 32 + b);
                consider(n, self.priority(n));
            }
        }
        best
    }

    /// The execution priority: the most urgent active exception, boosted by PRIMASK
    /// (to 0) and BASEPRI (B1.5.4).
    pub fn execution_priority(&self, primask: bool, basepri: u8) -> i16 {
        let mut p = self
            .active
            .iter()
            .map(|&n| self.priority(n))
            .min()
            .unwrap_or(THREAD_PRIORITY);
        if basepri != 0 {
            p = p.min(self.group(basepri));
        }
        if primask {
            p = p.min(0);
        }
        p
    }

    /// Clear the pending state of an exception being entered.
    pub fn take(&mut self, n: u16) {
        match n {
            NMI => self.nmi_pending = false,
            HARD_FAULT => self.hard_fault_pending = false,
            PENDSV => self.pendsv_pending = false,
            SYSTICK => self.systick_pending = false,
            n if n >= 16 => self.unpend_irq(n - 16),
            _ => {}
        }
        self.active.push(n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basepri_masks_equal_and_lower_urgency_only() {
        let mut n = Nvic::default();
        n.ipr[18] = 0xD0; // RTIC priority 3 of 4 bits
        n.ipr[38] = 0xE0; // priority 2
        n.enabled[0] = 1 << 18;
        n.enabled[1] = 1 << (38 - 32);
        n.pend_irq(18);
        n.pend_irq(38);
        assert_eq!(n.most_urgent_pending(), Some((irq(18), 0xD0)));
        // A priority-2 lock (BASEPRI = 0xE0) lets priority 3 through, not priority 2.
        assert!(0xD0 < n.execution_priority(false, 0xE0));
        assert!(0xE0 >= n.execution_priority(false, 0xE0));
        // PRIMASK masks both; HardFault (-1) still preempts.
        assert!(0xD0 >= n.execution_priority(true, 0));
        assert!(-1 < n.execution_priority(true, 0));
        // Nesting: the priority-3 handler active blocks another priority 3.
        n.take(irq(18));
        assert_eq!(n.execution_priority(false, 0), 0xD0);
    }
}
