//! What surrounds the DFL in the loop, with no IPC: the inbox its plans arrive in, the
//! monitor that judges every sample's deadline, and [`InnerLoop`], the three together as
//! the DFL process and the in-process loop step them every inner tick.

use crate::Dfl;
use protocol::{
    Actuation, CommandMode, DeadlineVerdict, Estimate, Header, PLAN_MISSING, Plan, PlanStatus,
    Scenario,
};

/// Samples a plan arrives late in lockstep: 0 if its solve took at most `Ts`, else
/// `ceil(solve / Ts)` (README, "Deadlines": timing violations behave as in real time).
pub fn late_samples(solve_ns: u64, ts_s: f64) -> u64 {
    let solve_s = solve_ns as f64 * 1e-9;
    if solve_s <= ts_s {
        0
    } else {
        (solve_s / ts_s).ceil() as u64
    }
}

/// When plans reach the DFL. In lockstep a plan is held until its arrival sample
/// ([`late_samples`]); in real time it is usable as soon as it is received.
pub struct PlanInbox {
    lockstep: bool,
    ts_s: f64,
    /// `(arrival sample, plan)` not yet offered to the DFL.
    pending: Vec<(u64, Plan)>,
    /// Newest sample a plan has been received for.
    newest_received: Option<u64>,
}

impl PlanInbox {
    pub fn new(lockstep: bool, ts_s: f64) -> PlanInbox {
        PlanInbox {
            lockstep,
            ts_s,
            pending: Vec::with_capacity(8),
            newest_received: None,
        }
    }

    /// Takes a received plan; returns the sample it becomes usable at.
    pub fn receive(&mut self, plan: &Plan) -> u64 {
        let arrival = if self.lockstep {
            plan.sample + self.late(plan)
        } else {
            0
        };
        self.newest_received = self.newest_received.max(Some(plan.sample));
        self.pending.push((arrival, *plan));
        arrival.max(plan.sample)
    }

    /// Lockstep: samples plan(k) arrives late (its production time: solve plus any
    /// injected delay).
    pub fn late(&self, plan: &Plan) -> u64 {
        late_samples(plan.solve_ns + plan.injected_delay_ns, self.ts_s)
    }

    /// Whether plan(`sample`) (or a newer one) has been received.
    pub fn has_received(&self, sample: u64) -> bool {
        self.newest_received.is_some_and(|s| s >= sample)
    }

    /// Lockstep: whether the DFL must wait for plan(`sample`) before commanding its first
    /// tick. A DFL that has followed the run waits for every plan; one that joined later
    /// (a restart or a replacement) cannot wait for a plan published before it listened,
    /// so it waits only once it has received the plan of the previous sample.
    pub fn must_wait_for(&self, sample: u64) -> bool {
        self.lockstep
            && !self.has_received(sample)
            && (sample == 0 || self.has_received(sample - 1))
    }

    /// Offers the DFL every plan that has arrived by `current_sample`.
    pub fn release(&mut self, current_sample: u64, dfl: &mut Dfl) {
        self.pending.retain(|(arrival, plan)| {
            let arrived = *arrival <= current_sample;
            if arrived {
                dfl.offer(plan);
            }
            !arrived
        });
    }
}

/// Judges every sample's deadline: plan(k) must reach the DFL, solved, by `t_k + Ts`.
/// Sample k is judged at the first tick of sample k + 1, when its deadline has passed.
#[derive(Debug, Clone)]
pub struct DeadlineMonitor {
    period_ns: u64,
    /// `(sample, arrival after t_k in ns, status code, production ns)` of received plans
    /// not yet judged.
    arrivals: Vec<(u64, u64, u32, u64)>,
    /// Mode of the first command of the sample being run.
    current: Option<(u64, CommandMode)>,
    misses: u32,
}

impl DeadlineMonitor {
    pub fn new(ts_s: f64) -> DeadlineMonitor {
        DeadlineMonitor {
            period_ns: (ts_s * 1e9).round() as u64,
            arrivals: Vec::with_capacity(8),
            current: None,
            misses: 0,
        }
    }

    /// Misses so far (the live counter).
    pub fn misses(&self) -> u32 {
        self.misses
    }

    /// A plan reached the DFL `arrival_ns` after the start of its sample.
    pub fn on_plan(&mut self, plan: &Plan, arrival_ns: u64) {
        if self.arrivals.iter().all(|a| a.0 != plan.sample) {
            self.arrivals.push((
                plan.sample,
                arrival_ns,
                plan.status,
                plan.solve_ns + plan.injected_delay_ns,
            ));
        }
    }

    /// The first command of `sample` was given in `mode`. Returns the verdict on the
    /// previous sample, whose deadline has now passed.
    pub fn sample_started(&mut self, sample: u64, mode: CommandMode) -> Option<DeadlineVerdict> {
        let previous = self.current.replace((sample, mode));
        let (judged, fallback) = previous.filter(|(s, _)| *s < sample)?;
        let found = self.arrivals.iter().find(|a| a.0 == judged).copied();
        self.arrivals.retain(|a| a.0 > judged);
        let (arrival_ns, status, production_ns) =
            found.map_or((u64::MAX, PLAN_MISSING, 0), |a| (a.1, a.2, a.3));
        let met = status == PlanStatus::Solved as u32 && arrival_ns <= self.period_ns;
        if !met {
            self.misses += 1;
        }
        Some(DeadlineVerdict {
            header: Header::default(),
            sample: judged,
            met: u32::from(met),
            status,
            production_ns,
            arrival_ns,
            fallback: fallback as u32,
            misses_total: self.misses,
        })
    }
}

/// The DFL with its plan inbox and deadline monitor: every inner tick of the DFL role, in
/// one process or another (README, "Deadlines").
pub struct InnerLoop {
    pub dfl: Dfl,
    inbox: PlanInbox,
    monitor: DeadlineMonitor,
    inner_steps: u64,
    ts_s: f64,
}

impl InnerLoop {
    /// `lockstep`: plans arrive when their solve time says ([`PlanInbox`]).
    pub fn new(scenario: &Scenario, lockstep: bool) -> InnerLoop {
        let ts_s = scenario.timing.ts_s;
        InnerLoop {
            dfl: Dfl::new(scenario),
            inbox: PlanInbox::new(lockstep, ts_s),
            monitor: DeadlineMonitor::new(ts_s),
            inner_steps: scenario.timing.inner_steps as u64,
            ts_s,
        }
    }

    /// A plan received. `arrival_ns`: in real time, how long after the start of its
    /// sample it came; in lockstep `None`, the arrival following from its solve time.
    pub fn receive(&mut self, plan: &Plan, arrival_ns: Option<u64>) {
        self.inbox.receive(plan);
        let arrival_ns =
            arrival_ns.unwrap_or_else(|| (self.inbox.late(plan) as f64 * self.ts_s * 1e9) as u64);
        self.monitor.on_plan(plan, arrival_ns);
    }

    /// The sample of inner tick `tick` and whether `tick` is its first.
    pub fn sample_of(&self, tick: u64) -> (u64, bool) {
        (
            tick / self.inner_steps,
            tick.is_multiple_of(self.inner_steps),
        )
    }

    /// The sample whose plan the command for `tick` may wait for: on the first tick of a
    /// sample whose plan has not been received. In lockstep the DFL must wait
    /// ([`InnerLoop::must_wait_for`]); in real time it waits for a share of the tick.
    pub fn awaited_plan(&self, tick: u64) -> Option<u64> {
        let (sample, first_tick) = self.sample_of(tick);
        (first_tick && !self.inbox.has_received(sample)).then_some(sample)
    }

    /// See [`PlanInbox::must_wait_for`].
    pub fn must_wait_for(&self, sample: u64) -> bool {
        self.inbox.must_wait_for(sample)
    }

    /// The command for `[t_tick, t_tick+1)` from `estimate`, after releasing the plans
    /// that have arrived; on the first tick of a sample, the verdict on the previous one
    /// (stamped with the command's header).
    pub fn command(
        &mut self,
        estimate: &Estimate,
        tick: u64,
    ) -> (Actuation, Option<DeadlineVerdict>) {
        let (sample, first_tick) = self.sample_of(tick);
        self.inbox.release(sample, &mut self.dfl);
        let mut actuation = self.dfl.step(estimate, tick);
        let verdict = match actuation.mode() {
            Some(mode) if first_tick => self.monitor.sample_started(sample, mode),
            _ => None,
        }
        .map(|verdict| DeadlineVerdict {
            header: actuation.header,
            ..verdict
        });
        actuation.deadline_misses = self.monitor.misses();
        (actuation, verdict)
    }

    /// The fallback brake for `tick`, on the DFL's own clock (see [`Dfl::brake`]).
    pub fn brake(&mut self, tick: u64) -> Actuation {
        let mut actuation = self.dfl.brake(tick);
        actuation.deadline_misses = self.monitor.misses();
        actuation
    }
}

/// Real time: after this many inner ticks without an estimate the DFL brakes on its own.
pub const SILENT_TICKS: u64 = 3;

/// Real time: a silent estimator (dead, or stalled) must not leave the plant holding the
/// last command. After [`SILENT_TICKS`] inner ticks without an estimate the DFL brakes on
/// its own clock (the brake needs only zeta), then every tick, until estimates come again.
#[derive(Debug, Clone, Copy, Default)]
pub struct SilenceWatch {
    /// The newest tick commanded, from an estimate or braking alone.
    last_tick: Option<u64>,
    braking_alone: bool,
}

impl SilenceWatch {
    /// Whether an estimate of `tick` comes too late: a command for it was given already.
    pub fn is_stale(&self, tick: u64) -> bool {
        self.last_tick.is_some_and(|last| tick <= last)
    }

    /// The command for `tick` was given from an estimate.
    pub fn heard(&mut self, tick: u64) {
        self.last_tick = Some(tick);
        self.braking_alone = false;
    }

    fn silent_ticks(&self) -> u64 {
        if self.braking_alone { 1 } else { SILENT_TICKS }
    }

    /// With the clock in tick `now_tick`: the tick to brake at now, if the estimator has
    /// been silent for too long (never before the first estimate).
    pub fn brake_due(&mut self, now_tick: u64) -> Option<u64> {
        let last = self.last_tick?;
        (now_tick >= last + self.silent_ticks()).then(|| {
            self.last_tick = Some(now_tick);
            self.braking_alone = true;
            now_tick
        })
    }

    /// The tick at which to look again for silence.
    pub fn next_check(&self) -> Option<u64> {
        self.last_tick.map(|last| last + self.silent_ticks())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_silent_estimator_is_braked_for_after_silent_ticks_then_every_tick() {
        let mut watch = SilenceWatch::default();
        assert_eq!(
            watch.brake_due(100),
            None,
            "no estimate yet: nothing to hold"
        );
        watch.heard(10);
        assert!(watch.is_stale(10) && !watch.is_stale(11));
        assert_eq!(watch.next_check(), Some(10 + SILENT_TICKS));
        assert_eq!(watch.brake_due(10 + SILENT_TICKS - 1), None);
        assert_eq!(watch.brake_due(10 + SILENT_TICKS), Some(13));
        assert_eq!(watch.next_check(), Some(14), "braking alone: every tick");
        assert_eq!(watch.brake_due(13), None);
        assert_eq!(watch.brake_due(14), Some(14));
        assert!(
            watch.is_stale(14),
            "an estimate of a braked tick is too late"
        );
        watch.heard(15);
        assert_eq!(
            watch.brake_due(16),
            None,
            "estimates again: back to the silent limit"
        );
        assert_eq!(watch.next_check(), Some(15 + SILENT_TICKS));
    }
}
