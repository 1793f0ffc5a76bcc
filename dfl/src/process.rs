//! `scmpc dfl`: on each estimate, apply the newest plan covering the current sample and
//! publish the actuation. At a sample boundary the DFL first waits for plan(k): in
//! lockstep until it comes; in real time until [`PLAN_WAIT_FRACTION`] of the inner tick
//! has passed, then it falls back to the shifted previous plan (the plant only takes the
//! command at the end of the tick, so waiting within it costs nothing).

use crate::{InnerLoop, SilenceWatch};
use protocol::clock::{monotonic_ns, tick_at};
use protocol::ipc::{ACTUATION, DEADLINE, ESTIMATE, PLAN};
use protocol::runtime::{INPUT_TIMEOUT, Link, Next, ProcessArgs, ProcessError, RunMode};
use protocol::{Actuation, DeadlineVerdict, Estimate, Plan, Role};
use std::collections::VecDeque;
use std::time::Duration;

/// Share of an inner tick the real-time DFL waits for the plan of a new sample.
pub const PLAN_WAIT_FRACTION: f64 = 0.8;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Dfl)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let plans = link.input::<Plan>(PLAN, Role::Mpc)?;
    let actuation = link.output::<Actuation>(ACTUATION)?;
    let deadlines = link.output::<DeadlineVerdict>(DEADLINE)?;

    let timing = &args.scenario.timing;
    let lockstep = args.mode == RunMode::Lockstep;
    let mut inner = InnerLoop::new(&args.scenario, lockstep);
    let mut queue: VecDeque<(Estimate, u64)> = VecDeque::with_capacity(16);
    let mut watch = SilenceWatch::default();
    let mut last_estimate_ns = monotonic_ns();
    // Whether the plant takes this process's commands (not before the orchestrator has
    // said so, nor while it warms up as a replacement).
    let mut commanding = false;
    link.run(&[&estimates, &plans], &[&actuation, &deadlines], |ctl| {
        // The periodic input first: its receipt time is the hop latency.
        estimates.take(|e, latency| queue.push_back((e, latency)))?;
        plans.take(|p, _| {
            let sample_start_ns = ctl.at_ns(p.sample as f64 * timing.ts_s).unwrap_or(0);
            let arrival_ns = (!lockstep).then(|| monotonic_ns().saturating_sub(sample_start_ns));
            inner.receive(&p, arrival_ns);
        })?;
        let mut wait_for = None;
        while let Some(&(e, latency)) = queue.front() {
            let tick = e.header.tick;
            if watch.is_stale(tick) {
                queue.pop_front(); // older than a command already given (braking)
                continue;
            }
            if let Some(sample) = inner.awaited_plan(tick) {
                if inner.must_wait_for(sample) {
                    break;
                }
                let give_up_s = (tick as f64 + PLAN_WAIT_FRACTION) * timing.dt_s();
                let give_up_ns = ctl.at_ns(give_up_s).unwrap_or(0);
                let now = monotonic_ns();
                if !lockstep && now < give_up_ns {
                    wait_for = Some(Duration::from_nanos(give_up_ns - now));
                    break;
                }
            }
            queue.pop_front();
            if !commanding {
                // Not (yet) driving the plant: follow the zeta it is driven with.
                inner.dfl.adopt_zeta(e.state[3]);
            }
            commanding = ctl.producing(Role::Dfl, args.epoch, tick);
            // Orphaned (the orchestrator is gone): brake to rest before the process exits.
            let (mut act, verdict) = if ctl.orphaned {
                (inner.brake(tick), None)
            } else {
                inner.command(&e, tick)
            };
            act.header.input_latency_ns = latency.min(u64::from(u32::MAX)) as u32;
            if let Some(verdict) = verdict {
                deadlines.send(verdict)?;
            }
            actuation.send(act)?;
            watch.heard(tick);
            last_estimate_ns = monotonic_ns();
        }
        // Real time: brake on the DFL's own clock while the estimator is silent.
        if let (false, Some(start_ns)) = (lockstep, ctl.start_ns) {
            let now = monotonic_ns();
            if let Some(tick) = watch.brake_due(tick_at(start_ns, now, timing.dt_s())) {
                if now.saturating_sub(last_estimate_ns) > INPUT_TIMEOUT.as_nanos() as u64 {
                    return Err(ProcessError::InputLost(INPUT_TIMEOUT));
                }
                actuation.send(inner.brake(tick))?;
            }
            if let Some(next_ns) = watch
                .next_check()
                .and_then(|t| ctl.at_ns(timing.tick_time_s(t)))
            {
                let until = Duration::from_nanos(next_ns.saturating_sub(now).max(100_000));
                wait_for = Some(wait_for.map_or(until, |w: Duration| w.min(until)));
            }
        }
        // No scheduled spin here (unlike the estimator): on two cores a third spinning
        // process starves the plant and the estimator (measured: README).
        Ok(Next::Wait(wait_for))
    })
}
