//! `scmpc mpc`: the [`MpcTask`] as a process: plan(k) solved and published for every
//! sample boundary estimate it takes.

use crate::task::MpcTask;
use protocol::clock::RunMode;
use protocol::ipc::{ESTIMATE, Input, PLAN, ROUTE};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError};
use protocol::{Estimate, Plan, Role, Route};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut task = MpcTask::new(&args.scenario).map_err(|e| ProcessError::Setup(e.to_string()))?;
    let link = Link::open(args, Role::Mpc)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let routes = link.input::<Route>(ROUTE, Role::Planner)?;
    let plans = link.output::<Plan>(PLAN)?;
    let inputs: &[&dyn Input] = if task.follows_route() {
        &[&estimates, &routes]
    } else {
        &[&estimates]
    };
    // The sample (its start, s) whose rehearsal is done.
    let mut rehearsed_for = None;
    link.run(inputs, &[&plans], |context| {
        routes.take(|r, _| task.hear_route(r))?;
        estimates.take(|e, latency| task.hear_estimate(e, latency))?;
        while let Some(plan) = task.step(context) {
            context.clock.hold(plan.injected_delay_ns);
            plans.send(plan)?;
        }
        let due_s = task.next_due_s();
        // Real time: asleep for most of `Ts`, the step would start with cold caches; a
        // rehearsal shortly before the sample warms them (lockstep never sleeps).
        let clock = &context.clock;
        if clock.mode() == RunMode::Realtime && rehearsed_for != Some(due_s) {
            let at_s = task.rehearsal_s();
            if !clock.is_past(at_s) {
                return Ok(Next::At(at_s));
            }
            // Not when it is late: the estimate would wait for it.
            if !clock.is_past(at_s + 0.25 * (due_s - at_s)) {
                task.rehearse();
            }
            rehearsed_for = Some(due_s);
        }
        // Only every M-th estimate matters: rather than waking for each one (and taking a
        // core from the DFL), expect the next sample's.
        Ok(Next::expect(&estimates, Some(due_s)))
    })
}
