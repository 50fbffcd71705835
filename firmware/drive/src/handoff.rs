//! The hand-over between the control period and the adaptation task: two bounded
//! lock-free queues, what each side does when its queue is full, and the adaptation
//! task's loop. The firmware's tasks and hil-sim's rig call this same code on the same
//! queue types, so a rig whose adaptation task runs late drops exactly as the firmware.
//!
//! - Samples, control period → task ([`HandoffQueue`]): [`ControlPeriod::hand_over`]. A
//!   full queue drops the sample and counts it (`Snapshot::handoffs_dropped`): the task
//!   starved, its coefficients lag, nothing else.
//! - New banks, task → control period ([`BankQueue`]), and back ([`SpareQueue`]): the
//!   task keeps a copy of the decoupling vector the control period holds (every update
//!   it queued, in force in the copy as it was queued), and at a new bank it builds the
//!   bank's vector whole in a spare buffer and hands it over ahead of the bank's update.
//!   When that update is due the control period swaps the buffer for its own and hands
//!   the old one back ([`ControlPeriod::apply_due`]): a few pointer moves, where
//!   building the bank in the control interrupt took over a thousand cycles. Two
//!   buffers go round; without a spare at hand (a bank's update right after another)
//!   the control period builds the bank in place (slower, the same bits).
//! - Updates, task → control period ([`UpdateQueue`]): [`ControlPeriod::apply_due`] puts
//!   them in force when due and counts those applied after the period they were due in
//!   (`Snapshot::updates_late`: the task missed its deadline). An update the queue cannot
//!   take is counted (`AdaptReport::updates_dropped`) and owed: nothing else is queued
//!   until it went, a path's newest term replacing its older one, and a new bank first
//!   (`crate::adaptation`), so the front never runs on another bank than the adapter.
//!
//! Each side owns one end; neither ever blocks or masks the other.

use crate::adaptation::{AdaptReport, AdaptationTask};
use crate::control::ControlPeriod;
use crate::telemetry::Install;
use core::borrow::BorrowMut;
use heapless::spsc::{Consumer, Producer};
use mras::{AdaptSample, Change, Injection, InjectionUpdate, Trig};

/// The queue type of both directions (re-exported: a host harness uses this one).
pub use heapless::spsc::Queue;

/// Samples the adaptation task may lag behind by, plus the slot a `heapless` queue keeps
/// free: 15 periods (0.75 ms at 20 kHz), more than the task's longest run that
/// `cargo xtask perf` measures.
pub const HANDOFF_DEPTH: usize = 16;
/// Updates in flight (one per stride within the latency) beside a whole install or
/// bank (1 + `MAX_PATHS`), plus the free slot.
pub const UPDATE_DEPTH: usize = 2 * mras::MAX_PATHS;

/// Decoupling vectors in flight each way: two buffers go round, one of them in force
/// (plus the free slot).
pub const BANK_DEPTH: usize = 2;

/// Control period → adaptation task.
pub type HandoffQueue = Queue<AdaptSample, HANDOFF_DEPTH>;
/// Adaptation task → control period.
pub type UpdateQueue = Queue<InjectionUpdate, UPDATE_DEPTH>;
/// Adaptation task → control period: a new bank's decoupling vector.
pub type BankQueue<S = Injection> = Queue<Prepared<S>, BANK_DEPTH>;
/// Control period → adaptation task: the decoupling vector a new bank replaced.
pub type SpareQueue<S = Injection> = Queue<S, BANK_DEPTH>;

/// A new bank's decoupling vector, built whole for the bank's update due at `apply_at`
/// (the update and the vector's bank must both match for the swap).
#[derive(Debug)]
pub struct Prepared<S> {
    pub apply_at: u32,
    pub injection: S,
}

/// The producing end of a queue: the firmware's split [`Producer`], or a whole
/// [`Queue`] where one thread runs both sides (hil-sim).
pub trait Sender<T> {
    /// `Err` with the value when the queue is full.
    fn send(&mut self, value: T) -> Result<(), T>;
    /// Whether a value sent now would be taken.
    fn ready(&self) -> bool;
}

/// The consuming end of a queue.
pub trait Receiver<T> {
    fn peek(&self) -> Option<&T>;
    fn receive(&mut self) -> Option<T>;
}

impl<T, const N: usize> Sender<T> for Producer<'_, T, N> {
    #[inline(always)]
    fn send(&mut self, value: T) -> Result<(), T> {
        self.enqueue(value)
    }
    #[inline(always)]
    fn ready(&self) -> bool {
        Producer::ready(self)
    }
}

impl<T, const N: usize> Sender<T> for Queue<T, N> {
    #[inline(always)]
    fn send(&mut self, value: T) -> Result<(), T> {
        self.enqueue(value)
    }
    #[inline(always)]
    fn ready(&self) -> bool {
        !self.is_full()
    }
}

impl<T, const N: usize> Receiver<T> for Consumer<'_, T, N> {
    #[inline(always)]
    fn peek(&self) -> Option<&T> {
        Consumer::peek(self)
    }
    #[inline(always)]
    fn receive(&mut self) -> Option<T> {
        self.dequeue()
    }
}

impl<T, const N: usize> Receiver<T> for Queue<T, N> {
    #[inline(always)]
    fn peek(&self) -> Option<&T> {
        Queue::peek(self)
    }
    #[inline(always)]
    fn receive(&mut self) -> Option<T> {
        self.dequeue()
    }
}

impl<T: Trig, S: BorrowMut<Injection>> ControlPeriod<T, S> {
    /// Before [`ControlPeriod::step`]: put in force, in order, the adaptation's updates
    /// due by the coming period (a new bank by the vector the task built for it, the
    /// replaced one handed back); the rest stay queued.
    #[inline(always)]
    pub fn apply_due(
        &mut self,
        updates: &mut impl Receiver<InjectionUpdate>,
        banks: &mut impl Receiver<Prepared<S>>,
        spares: &mut impl Sender<S>,
    ) {
        while let Some(u) = updates.peek() {
            let applied = match u.change {
                Change::Term { .. } => self.apply(u),
                Change::Bank(_) => self.apply_bank(u, banks, spares),
            };
            if !applied {
                break;
            }
            updates.receive();
        }
    }

    /// A bank's update (a few times per commissioning: out of the common path).
    #[cold]
    #[inline(never)]
    fn apply_bank(
        &mut self,
        u: &InjectionUpdate,
        banks: &mut impl Receiver<Prepared<S>>,
        spares: &mut impl Sender<S>,
    ) -> bool {
        if !self.tracker().is_due(u) {
            return false;
        }
        let built = banks.peek().is_some_and(|p| {
            p.apply_at == u.apply_at
                && matches!(u.change, Change::Bank(b) if *p.injection.borrow().bank() == b)
        });
        if built {
            if let Some(p) = banks.receive() {
                let replaced = self.swap_bank(u, p.injection);
                // Two buffers go round, so the way back always has room (one refused
                // would be dropped, and later banks built in place).
                let _ = spares.send(replaced);
                return true;
            }
        }
        // No vector was built for this update (no spare was at hand): built in place.
        // Another update's stays queued for it.
        self.apply(u)
    }

    /// After [`ControlPeriod::step`]: hand this period's sample to the adaptation task,
    /// or count it dropped when the queue is full. Returns whether there was a sample
    /// (the caller then wakes the task).
    #[inline(always)]
    pub fn hand_over(&mut self, handoff: &mut impl Sender<AdaptSample>) -> bool {
        let Some(&s) = self.handoff() else {
            return false;
        };
        if handoff.send(s).is_err() {
            self.note_handoff_dropped();
        }
        true
    }
}

impl<S: BorrowMut<Injection>> AdaptationTask<S> {
    /// One run of the adaptation task: a decoupling vector handed back taken as the
    /// spare, the bank the last run deferred and the updates still owed, then the coefficients `install` (from the
    /// supervisor's mailbox) if any, then every handed-over sample in order (during a
    /// survey's end, only up to the first of its samples, the survey's last sample among
    /// them). `publish` gets the report after an install and after each snapshot sample
    /// ([`AdaptSample::REPORT`]).
    pub fn run(
        &mut self,
        handoff: &mut impl Receiver<AdaptSample>,
        updates: &mut impl Sender<InjectionUpdate>,
        banks: &mut impl Sender<Prepared<S>>,
        spares: &mut impl Receiver<S>,
        install: Option<Install>,
        mut publish: impl FnMut(&AdaptReport),
    ) {
        self.take_spare(spares);
        self.send_deferred(updates, banks);
        self.send_owed(updates, banks);
        if let Some(i) = install {
            self.install(&i, updates, banks);
            publish(self.report());
        }
        while let Some(s) = handoff.receive() {
            let ending_round = self.adapter().ending_round();
            self.step(&s, updates, banks);
            if s.has(AdaptSample::REPORT) {
                publish(self.report());
            }
            // A survey's end works one step a sample, and one such sample a run (the
            // spectrum, on the survey's last sample, among them): the samples behind it
            // wait for the next period's run, so that no run spans a control period
            // (their updates are due a fixed latency after them).
            if ending_round || self.adapter().ending_round() {
                break;
            }
        }
    }
}
