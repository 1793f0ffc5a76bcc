//! The run's clock: lockstep grants every tick and records it before the next; real time
//! publishes the time of tick 0 and records ticks as they complete.

use super::*;

impl Driver<'_> {
    /// Current tick: the next to record in lockstep, the wall clock's in real time.
    pub(super) fn now_tick(&self) -> u64 {
        match self.mode {
            RunMode::Lockstep => self.cursor,
            RunMode::Realtime => {
                tick_at(self.start_ns, monotonic_ns(), self.scenario.timing.dt_s())
            }
        }
    }

    pub(super) fn lockstep(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<Outcome> {
        let ticks = self.scenario.tick_count();
        let inner_steps = self.scenario.timing.inner_steps as u64;
        for tick in 0..=ticks {
            self.session.command(ControlCommand::Grant, tick, 0)?;
            let boundary = tick.is_multiple_of(inner_steps) && tick < ticks;
            let mut last_progress = Instant::now();
            loop {
                let done = if tick == ticks {
                    self.slots.get(&tick).is_some_and(|s| s.truth.is_some())
                } else {
                    self.slots.get(&tick).is_some_and(TickSlot::complete)
                        && (!boundary || self.plans.contains_key(&(tick / inner_steps)))
                };
                if done {
                    break;
                }
                if let Some(outcome) = self.check()? {
                    return Ok(outcome);
                }
                if last_progress.elapsed() > TICK_TIMEOUT {
                    bail!("tick {tick} made no progress for {TICK_TIMEOUT:?}: a process hung");
                }
                let before = self.slots.len() + self.plans.len();
                self.pump(waitset)?;
                if self.slots.len() + self.plans.len() != before {
                    last_progress = Instant::now();
                }
            }
            let slot = self.slots.remove(&tick).unwrap_or_default();
            if tick == ticks {
                return Ok(self.recorder.end_of_run(slot.truth.as_ref()));
            }
            let no_route = self.record_plans()?;
            if let Some(outcome) = self.record(tick, slot)?.or(no_route) {
                return Ok(outcome);
            }
            self.cursor = tick + 1;
            self.supervise()?;
        }
        Ok(self.recorder.end_of_run(None))
    }

    pub(super) fn realtime(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<Outcome> {
        let ticks = self.scenario.tick_count();
        let inner_steps = self.scenario.timing.inner_steps as u64;
        self.start_ns = monotonic_ns() + START_LEAD.as_nanos() as u64;
        self.session
            .command(ControlCommand::Start, 0, self.start_ns)?;
        let end_ns = self.start_ns + (self.scenario.duration_s * 1e9) as u64;
        let give_up_ns = end_ns + 5_000_000_000;
        let mut next = 0u64;
        loop {
            if let Some(outcome) = self.check()? {
                return Ok(outcome);
            }
            if monotonic_ns() > give_up_ns {
                bail!("the run did not finish within 5 s after its end: a process hung");
            }
            self.pump(waitset)?;
            if let Some(outcome) = self.record_plans()? {
                return Ok(outcome);
            }
            self.supervise()?;
            while next <= ticks {
                let complete = self.slots.get(&next).is_some_and(|s| {
                    if next == ticks {
                        s.truth.is_some()
                    } else {
                        s.complete()
                    }
                });
                let overdue = self
                    .newest_truth
                    .is_some_and(|t| t >= next + 2 * inner_steps);
                if !complete && !overdue {
                    break;
                }
                let slot = self.slots.remove(&next).unwrap_or_default();
                if next == ticks {
                    return Ok(self.recorder.end_of_run(slot.truth.as_ref()));
                }
                let commanded =
                    slot.truth.is_some() && slot.measurement.is_some() && slot.actuation.is_some();
                if !complete && !commanded {
                    self.record_gaps += 1;
                    self.recorder
                        .event("record_gap", serde_json::json!({ "tick": next }))?;
                } else if let Some(outcome) = self.record(next, slot)? {
                    return Ok(outcome);
                }
                next += 1;
                self.cursor = next;
            }
        }
    }
}
