//! The hand-over between the control period and the adaptation task: two bounded
//! lock-free queues, what each side does when its queue is full, and the adaptation
//! task's loop. The firmware's tasks and hil-sim's rig call this same code on the same
//! queue types, so a rig whose adaptation task runs late drops exactly as the firmware.
//!
//! - Samples, control period → task ([`HandoffQueue`]): [`ControlPeriod::hand_over`]. A
//!   full queue drops the sample and counts it (`Snapshot::handoffs_dropped`): the task
//!   starved, its coefficients lag, nothing else.
//! - Bank plans, task → control period ([`PlanQueue`]): a new bank worked out in the task
//!   against the one in force ([`mras::BankPlan`]), which the control period takes when
//!   the bank's update is due, so that putting it in force only moves terms. Without
//!   its plan the control period works the bank out itself (slower, same result).
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
use heapless::spsc::{Consumer, Producer};
use mras::{AdaptSample, BankPlan, Change, InjectionUpdate, Trig};

/// The queue type of both directions (re-exported: a host harness uses this one).
pub use heapless::spsc::Queue;

/// Samples the adaptation task may lag behind by, plus the slot a `heapless` queue keeps
/// free: 15 periods (0.75 ms at 20 kHz), more than the task's longest run that
/// `cargo xtask perf` measures.
pub const HANDOFF_DEPTH: usize = 16;
/// Updates in flight (one per stride within the latency) beside a whole install or
/// bank (1 + `MAX_PATHS`), plus the free slot.
pub const UPDATE_DEPTH: usize = 2 * mras::MAX_PATHS;

/// Bank plans in flight: banks change seconds apart, one at a time (plus the free slot).
pub const PLAN_DEPTH: usize = 2;

/// Control period → adaptation task.
pub type HandoffQueue = Queue<AdaptSample, HANDOFF_DEPTH>;
/// Adaptation task → control period.
pub type UpdateQueue = Queue<InjectionUpdate, UPDATE_DEPTH>;
/// Adaptation task → control period: the plan of each new bank.
pub type PlanQueue = Queue<BankPlan, PLAN_DEPTH>;

/// The producing end of a queue: the firmware's split [`Producer`], or a whole
/// [`Queue`] where one thread runs both sides (hil-sim).
pub trait Sender<T> {
    /// `Err` with the value when the queue is full.
    fn send(&mut self, value: T) -> Result<(), T>;
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
}

impl<T, const N: usize> Sender<T> for Queue<T, N> {
    #[inline(always)]
    fn send(&mut self, value: T) -> Result<(), T> {
        self.enqueue(value)
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

impl<T: Trig> ControlPeriod<T> {
    /// Before [`ControlPeriod::step`]: put in force, in order, the adaptation's updates
    /// due by the coming period (a new bank with the plan the task sent for it); the
    /// rest stay queued.
    #[inline(always)]
    pub fn apply_due(
        &mut self,
        updates: &mut impl Receiver<InjectionUpdate>,
        plans: &mut impl Receiver<BankPlan>,
    ) {
        while let Some(u) = updates.peek() {
            let applied = match u.change {
                Change::Term { .. } => self.apply(u),
                Change::Bank(_) => self.apply_bank(u, plans),
            };
            if !applied {
                break;
            }
            updates.receive();
        }
    }

    /// A bank's update: its plan is taken when it is due (a few times per
    /// commissioning: out of the common path).
    #[cold]
    #[inline(never)]
    fn apply_bank(&mut self, u: &InjectionUpdate, plans: &mut impl Receiver<BankPlan>) -> bool {
        // Not due: its plan stays queued with it.
        if !self.tracker().is_due(u) {
            return false;
        }
        // Read where it lies in its queue, then dropped: copied out of the queue first,
        // its hundred bytes cost the control interrupt about 460 cycles.
        let applied = self.apply_planned(u, plans.peek());
        let _ = plans.receive();
        applied
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

impl AdaptationTask {
    /// One run of the adaptation task: the updates still owed first, then the
    /// coefficients `install` (from the supervisor's mailbox) if any, then every
    /// handed-over sample in order (during a survey's end, only up to the first of its
    /// samples, the survey's last sample among them). `publish` gets the report after an install and after
    /// each snapshot sample ([`AdaptSample::REPORT`]).
    pub fn run(
        &mut self,
        handoff: &mut impl Receiver<AdaptSample>,
        updates: &mut impl Sender<InjectionUpdate>,
        plans: &mut impl Sender<BankPlan>,
        install: Option<Install>,
        mut publish: impl FnMut(&AdaptReport),
    ) {
        self.send_owed(updates);
        if let Some(i) = install {
            self.install(&i, updates, plans);
            publish(self.report());
        }
        while let Some(s) = handoff.receive() {
            let ending_round = self.adapter().ending_round();
            self.step(&s, updates, plans);
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
