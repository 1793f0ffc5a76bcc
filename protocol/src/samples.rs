//! The boundary estimates a once-per-sample role (the MPC, the planner) has not answered
//! yet: an estimate that starts sample `k` is kept until the role answers it, and when the
//! role has fallen behind, a sample whose successor's time is past is not answered: only
//! the newest is.

use crate::task::Context;
use crate::{Estimate, Timing};
use std::collections::VecDeque;

/// The boundary estimates waiting, each with what the role keeps beside it (the MPC its
/// receipt latency), and the sample to answer next.
#[derive(Debug, Clone)]
pub struct SampleQueue<T> {
    timing: Timing,
    waiting: VecDeque<(Estimate, T)>,
    next_sample: u64,
}

impl<T: Copy> SampleQueue<T> {
    pub fn new(timing: &Timing) -> SampleQueue<T> {
        SampleQueue {
            timing: timing.clone(),
            waiting: VecDeque::with_capacity(16),
            next_sample: 0,
        }
    }

    /// An estimate heard: kept if it starts a sample not answered yet (a replay repeats
    /// one that was).
    pub fn hear(&mut self, estimate: Estimate, with: T) {
        let tick = estimate.header.tick;
        if self.timing.starts_sample(tick) && self.timing.sample_of(tick) >= self.next_sample {
            self.waiting.push_back((estimate, with));
        }
    }

    /// When the next sample starts, s.
    pub fn next_due_s(&self) -> f64 {
        self.timing.sample_time_s(self.next_sample)
    }

    /// The oldest estimate to answer, with its sample, after dropping those answered
    /// already (a replay heard in the same batch as the original) and those whose
    /// successor's time is past.
    pub fn oldest(&mut self, context: &impl Context) -> Option<(u64, Estimate, T)> {
        while let Some((e, _)) = self.waiting.front() {
            let answered = self.timing.sample_of(e.header.tick) < self.next_sample;
            let behind =
                (self.waiting.get(1)).is_some_and(|(next, _)| context.is_past(next.header.time_s));
            if !(answered || behind) {
                break;
            }
            self.waiting.pop_front();
        }
        let &(estimate, with) = self.waiting.front()?;
        Some((self.timing.sample_of(estimate.header.tick), estimate, with))
    }

    /// The oldest estimate is answered: the next sample is the one after it.
    pub fn answered(&mut self) {
        if let Some((estimate, _)) = self.waiting.pop_front() {
            self.next_sample = self.timing.sample_of(estimate.header.tick) + 1;
        }
    }
}
