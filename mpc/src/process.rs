//! `scmpc mpc`: on each estimate at a sample boundary, solve plan(k) and publish it. In
//! lockstep every boundary estimate is solved in order; in real time only the newest one
//! (a solve that overran `Ts` skips the samples it missed).

use crate::Mpc;
use protocol::ipc::{
    self, ControlState, ESTIMATE, Link, PLAN, ProcessArgs, ProcessError, RunMode, open_topic,
};
use protocol::{Estimate, Header, Plan, Role, StatusEvent};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut mpc = Mpc::new(&args.scenario).map_err(|e| ProcessError::Setup(e.to_string()))?;
    let link = Link::open(args, Role::Mpc)?;
    let mut ctl = ControlState::default();
    let estimates = open_topic::<Estimate>(&link.node, ESTIMATE)?.receiver_from(Role::Estimator)?;
    let plans = open_topic::<Plan>(&link.node, PLAN)?.sender(args.epoch)?;
    let waitset = ipc::waitset(true)?;
    let _guards = [
        link.control().attach(&waitset)?,
        estimates.attach(&waitset)?,
    ];
    link.report(StatusEvent::Ready)?;

    let inner_steps = args.scenario.timing.inner_steps as u64;
    let sample_ns = args.scenario.timing.ts_s * 1e9;
    let mut boundary: VecDeque<(Estimate, u64)> = VecDeque::with_capacity(16);
    let mut next_sample = 0u64;
    let mut cleared = false;
    loop {
        // The MPC wakes once per sample, possibly after a long solve: a schedule sent in
        // the meantime is applied before the estimates are judged. (The estimator and the
        // DFL apply it in housekeeping after every input; until then they keep taking the
        // old producer, which runs until the switch.)
        link.sync(&mut ctl, &[&estimates])?;
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
        if !cleared {
            // Consume the wake-ups, then take once more what came before that.
            if !link.housekeeping(&mut ctl, &[&estimates])? {
                return Ok(());
            }
            if ctl.take_replay() {
                plans.replay()?;
            }
            cleared = true;
            continue;
        }
        cleared = false;
        // Real time: only every M-th estimate matters; rather than waking for each one
        // (and taking a core from the DFL), poll at the next sample boundary.
        if let (RunMode::Realtime, Some(start_ns)) = (args.mode, ctl.start_ns) {
            let expected = start_ns + (next_sample as f64 * sample_ns) as u64;
            if ipc::spin_wait(expected, || estimates.has_samples()) {
                continue;
            }
        }
        if !link.wait(&waitset, None)? {
            return Ok(());
        }
    }
}
