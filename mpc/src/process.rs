//! `scmpc mpc`: on each estimate at a sample boundary, solve plan(k) and publish it. In
//! lockstep every boundary estimate is solved in order; in real time only the newest one
//! (a solve that overran `Ts` skips the samples it missed).

use crate::Mpc;
use protocol::ipc::{ESTIMATE, PLAN};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError, RunMode};
use protocol::{Estimate, Header, Plan, Role};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut mpc = Mpc::new(&args.scenario).map_err(|e| ProcessError::Setup(e.to_string()))?;
    let link = Link::open(args, Role::Mpc)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let plans = link.output::<Plan>(PLAN)?;

    let timing = &args.scenario.timing;
    let inner_steps = timing.inner_steps as u64;
    let mut boundary: VecDeque<(Estimate, u64)> = VecDeque::with_capacity(16);
    let mut next_sample = 0u64;
    link.run(&[&estimates], &[&plans], |ctl| {
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
        while let Some((e, latency)) = boundary.pop_front() {
            next_sample = e.header.tick / inner_steps + 1;
            let mut plan = mpc.step(e.header.tick / inner_steps, e.state, e.position_sigma());
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
        Ok(
            match (args.mode, ctl.at_ns(next_sample as f64 * timing.ts_s)) {
                (RunMode::Realtime, Some(at_ns)) => Next::Expect {
                    input: &estimates,
                    at_ns,
                },
                _ => Next::Wait(None),
            },
        )
    })
}
