//! `scmpc mpc`: on each estimate at a sample boundary, solve plan(k) and publish it. In
//! lockstep every boundary estimate is solved in order; in real time only the newest one
//! (a solve that overran `Ts` skips the samples it missed).
//!
//! With a planner (`planner.kind = "route"`) plan(k) follows the newest route of an
//! earlier sample, route(k - 1) in a whole run (the planner is never between the estimate
//! and the plan); in lockstep the MPC waits until it has heard route(k - 1) or a newer one
//! (a restarted planner answers the newest estimate), in real time it takes what it has.
//! Without any (the first sample, a planner not heard yet) it drives to the goal.

use crate::Mpc;
use protocol::ipc::{ESTIMATE, PLAN, ROUTE};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError, RunMode};
use protocol::{Estimate, Header, Plan, Role, Route};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut mpc = Mpc::new(&args.scenario).map_err(|e| ProcessError::Setup(e.to_string()))?;
    let link = Link::open(args, Role::Mpc)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let plans = link.output::<Plan>(PLAN)?;
    let follows_route = args.scenario.planner.is_on();
    let routes = link.input::<Route>(ROUTE, Role::Planner)?;

    let timing = &args.scenario.timing;
    let inner_steps = timing.inner_steps as u64;
    let mut boundary: VecDeque<(Estimate, u64)> = VecDeque::with_capacity(16);
    let mut next_sample = 0u64;
    // The newest routes heard, oldest first (a few samples' worth).
    let mut heard: VecDeque<Route> = VecDeque::with_capacity(4);
    let inputs: &[&dyn protocol::ipc::Input] = if follows_route {
        &[&estimates, &routes]
    } else {
        &[&estimates]
    };
    link.run(inputs, &[&plans], |ctl| {
        if follows_route {
            routes.take(|r, _| {
                if heard.len() == heard.capacity() {
                    heard.pop_front();
                }
                heard.push_back(r);
            })?;
        }
        estimates.take(|e, latency| {
            // Boundary estimates of samples not solved yet (a replay repeats one that was).
            let tick = e.header.tick;
            if tick.is_multiple_of(inner_steps) && tick / inner_steps >= next_sample {
                boundary.push_back((e, latency));
            }
        })?;
        if args.mode == RunMode::Realtime {
            while boundary.len() > 1 {
                boundary.pop_front();
            }
        }
        while let Some(&(e, latency)) = boundary.front() {
            let sample = e.header.tick / inner_steps;
            let awaited = follows_route && args.mode == RunMode::Lockstep && sample > 0;
            if awaited && heard.back().is_none_or(|r| r.sample + 1 < sample) {
                break; // route(k - 1) is on its way
            }
            boundary.pop_front();
            next_sample = sample + 1;
            let route = heard.iter().rev().find(|r| r.sample < sample);
            let mut plan = mpc.step_on_route(sample, e.state, e.position_sigma(), route);
            mpc.inject_faults(&mut plan, &args.scenario.fault);
            if args.mode == RunMode::Realtime && plan.injected_delay_ns > 0 {
                std::thread::sleep(std::time::Duration::from_nanos(plan.injected_delay_ns));
            }
            plan.header = Header {
                tick: e.header.tick,
                time_s: e.header.time_s,
                input_latency_ns: latency.min(u64::from(u32::MAX)) as u32,
                ..Header::default()
            };
            plans.send(plan)?;
        }
        // Real time: only every M-th estimate matters; rather than waking for each one
        // (and taking a core from the DFL), poll at the next sample boundary.
        Ok(match args.mode {
            RunMode::Realtime => Next::at_sample(ctl, &estimates, next_sample, timing.ts_s),
            RunMode::Lockstep => Next::Wait(None),
        })
    })
}
