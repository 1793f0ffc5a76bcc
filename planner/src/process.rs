//! `scmpc planner`: on each estimate at a sample boundary, route(k) (planned again when
//! [`Planner::step`] says so, else the newest route) published. In lockstep every boundary
//! estimate is answered in order; in real time only the newest one.

use crate::Planner;
use protocol::ipc::{ESTIMATE, ROUTE};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError, RunMode};
use protocol::{Estimate, Header, Role, Route};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut planner = Planner::new(&args.scenario);
    let link = Link::open(args, Role::Planner)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let routes = link.output::<Route>(ROUTE)?;

    let timing = &args.scenario.timing;
    let inner_steps = timing.inner_steps as u64;
    let mut boundary: VecDeque<Estimate> = VecDeque::with_capacity(16);
    let mut next_sample = 0u64;
    link.run(&[&estimates], &[&routes], |ctl| {
        estimates.take(|e, _| {
            let tick = e.header.tick;
            if tick.is_multiple_of(inner_steps) && tick / inner_steps >= next_sample {
                boundary.push_back(e);
            }
        })?;
        if args.mode == RunMode::Realtime {
            while boundary.len() > 1 {
                boundary.pop_front();
            }
        }
        while let Some(e) = boundary.pop_front() {
            let sample = e.header.tick / inner_steps;
            next_sample = sample + 1;
            let mut route = planner.step(sample, &e);
            route.header = Header {
                tick: e.header.tick,
                time_s: e.header.time_s,
                ..Header::default()
            };
            routes.send(route)?;
        }
        // Real time: poll at the next sample boundary rather than wake for every estimate.
        Ok(match args.mode {
            RunMode::Realtime => Next::at_sample(ctl, &estimates, next_sample, timing.ts_s),
            RunMode::Lockstep => Next::Wait(None),
        })
    })
}
