//! `scmpc dfl`: on each estimate, apply the newest plan covering the current sample and
//! publish the actuation. At a sample boundary the DFL first waits for plan(k): in
//! lockstep until it comes; in real time until [`PLAN_WAIT_FRACTION`] of the inner tick
//! has passed, then it falls back to the shifted previous plan (the plant only takes the
//! command at the end of the tick, so waiting within it costs nothing).

use crate::{DeadlineMonitor, Dfl, PlanInbox};
use protocol::clock::monotonic_ns;
use protocol::ipc::{
    self, ACTUATION, ControlState, DEADLINE, ESTIMATE, Link, PLAN, ProcessArgs, ProcessError,
    RunMode, open_topic,
};
use protocol::{Actuation, DeadlineVerdict, Estimate, Plan, Role, StatusEvent};
use std::collections::VecDeque;
use std::time::Duration;

/// Share of an inner tick the real-time DFL waits for the plan of a new sample.
pub const PLAN_WAIT_FRACTION: f64 = 0.8;
/// Real time: after this many inner ticks without an estimate the DFL brakes on its own.
pub const SILENT_TICKS: u64 = 3;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Dfl)?;
    let mut ctl = ControlState::default();
    let estimates = open_topic::<Estimate>(&link.node, ESTIMATE)?.receiver_from(Role::Estimator)?;
    let plans = open_topic::<Plan>(&link.node, PLAN)?.receiver_from(Role::Mpc)?;
    let actuation = open_topic::<Actuation>(&link.node, ACTUATION)?.sender(args.epoch)?;
    let deadlines = open_topic::<DeadlineVerdict>(&link.node, DEADLINE)?.sender(args.epoch)?;
    let waitset = ipc::waitset(true)?;
    let _guards = [
        link.control().attach(&waitset)?,
        estimates.attach(&waitset)?,
        plans.attach(&waitset)?,
    ];
    link.report(StatusEvent::Ready)?;

    let timing = &args.scenario.timing;
    let inner_steps = timing.inner_steps as u64;
    let dt_ns = timing.dt_s() * 1e9;
    let lockstep = args.mode == RunMode::Lockstep;
    let mut dfl = Dfl::new(&args.scenario);
    let mut inbox = PlanInbox::new(lockstep, timing.ts_s);
    let mut monitor = DeadlineMonitor::new(timing.ts_s);
    let sample_ns = timing.ts_s * 1e9;
    let mut queue: VecDeque<(Estimate, u64)> = VecDeque::with_capacity(16);
    let mut last_tick: Option<u64> = None;
    let mut last_estimate_ns = monotonic_ns();
    // Whether the plant takes this process's commands (not before the orchestrator has
    // said so, nor while it warms up as a replacement).
    let mut commanding = false;
    // Real time: commanding on the DFL's own clock, the estimator being silent.
    let mut braking_alone = false;
    let mut cleared = false;
    loop {
        // Hot path: samples straight from shared memory, the periodic input first (its
        // receipt time is the hop latency); system calls come after publishing.
        estimates.take(|e, latency| queue.push_back((e, latency)))?;
        plans.take(|p, _| {
            inbox.receive(&p);
            let arrival_ns = if lockstep {
                (inbox.late(&p) as f64 * sample_ns) as u64
            } else {
                let sample_start = ctl.start_ns.unwrap_or(0) + (p.sample as f64 * sample_ns) as u64;
                monotonic_ns().saturating_sub(sample_start)
            };
            monitor.on_plan(&p, arrival_ns);
        })?;
        let mut wait_for = None;
        while let Some(&(e, latency)) = queue.front() {
            let tick = e.header.tick;
            let sample = tick / inner_steps;
            if last_tick.is_some_and(|last| tick <= last) {
                queue.pop_front(); // older than a command already given (braking)
                continue;
            }
            if tick.is_multiple_of(inner_steps) && !inbox.has_received(sample) {
                if inbox.must_wait_for(sample) {
                    break;
                }
                let give_up_ns =
                    ctl.start_ns.unwrap_or(0) + ((tick as f64 + PLAN_WAIT_FRACTION) * dt_ns) as u64;
                let now = monotonic_ns();
                if !lockstep && now < give_up_ns {
                    wait_for = Some(Duration::from_nanos(give_up_ns - now));
                    break;
                }
            }
            queue.pop_front();
            inbox.release(sample, &mut dfl);
            if !commanding {
                // Not (yet) driving the plant: follow the zeta it is driven with.
                dfl.adopt_zeta(e.state[3]);
            }
            commanding = ctl.producing(Role::Dfl, args.epoch, tick);
            let mut act = dfl.step(&e, tick);
            act.header.input_latency_ns = latency.min(u64::from(u32::MAX)) as u32;
            if tick.is_multiple_of(inner_steps)
                && let Some(mode) = act.mode()
                && let Some(mut verdict) = monitor.sample_started(sample, mode)
            {
                verdict.header = act.header;
                deadlines.send(verdict)?;
            }
            act.deadline_misses = monitor.misses();
            actuation.send(act)?;
            last_tick = Some(tick);
            last_estimate_ns = monotonic_ns();
            braking_alone = false;
        }
        // Real time: a silent estimator (dead, or stalled) must not leave the plant holding
        // the last command: brake on the DFL's own clock, which needs only zeta. Once
        // braking so, command every tick.
        if let (false, Some(start_ns), Some(last)) = (lockstep, ctl.start_ns, last_tick) {
            let silent_ticks = |braking_alone| if braking_alone { 1 } else { SILENT_TICKS };
            let now = monotonic_ns();
            let due = (now.saturating_sub(start_ns) as f64 / dt_ns) as u64;
            if due >= last + silent_ticks(braking_alone) {
                if now.saturating_sub(last_estimate_ns) > ipc::INPUT_TIMEOUT.as_nanos() as u64 {
                    let _ = link.report(StatusEvent::InputLost);
                    return Err(ProcessError::InputLost(ipc::INPUT_TIMEOUT));
                }
                let mut act = dfl.brake(due);
                act.deadline_misses = monitor.misses();
                actuation.send(act)?;
                last_tick = Some(due);
                braking_alone = true;
            }
            let next_tick = last_tick.unwrap_or(last) + silent_ticks(braking_alone);
            let next_check = start_ns + (timing.tick_time_s(next_tick) * 1e9) as u64;
            let until = Duration::from_nanos(next_check.saturating_sub(now).max(100_000));
            wait_for = Some(wait_for.map_or(until, |w: Duration| w.min(until)));
        }
        if !cleared {
            // Consume the wake-ups, then take once more what came before that.
            if !link.housekeeping(&mut ctl, &[&estimates, &plans])? {
                return Ok(());
            }
            if ctl.take_replay() {
                actuation.replay()?;
                deadlines.replay()?;
            }
            cleared = true;
            continue;
        }
        cleared = false;
        // No scheduled spin here (unlike the estimator): on two cores a third spinning
        // process starves the plant and the estimator (measured: README).
        if !link.wait(&waitset, wait_for)? {
            return Ok(());
        }
    }
}
