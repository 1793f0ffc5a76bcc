//! `scmpc mpc`: the [`MpcTask`] as a process: plan(k) solved and published for every
//! sample boundary estimate it takes.

use crate::solver::ArrivalProbe;
use crate::task::MpcTask;
use protocol::ipc::{ESTIMATE, Input, PLAN, ROUTE};
use protocol::runtime::{ControlState, Link, Next, ProcessArgs, ProcessError, WARM_UP_LEAD_TICKS};
use protocol::{Estimate, Plan, Role, Route};
use std::cell::RefCell;
use std::rc::Rc;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let task = MpcTask::new(&args.scenario).map_err(|e| ProcessError::Setup(e.to_string()))?;
    let task = RefCell::new(task);
    let link = Link::open(args, Role::Mpc)?;
    let estimates = Rc::new(link.input::<Estimate>(ESTIMATE, Role::Estimator)?);
    let routes = link.input::<Route>(ROUTE, Role::Planner)?;
    let plans = link.output::<Plan>(PLAN)?;
    let inputs: &[&dyn Input] = if task.borrow().follows_route() {
        &[&*estimates, &routes]
    } else {
        &[&*estimates]
    };
    let step = |context: &ControlState| {
        let mut task = task.borrow_mut();
        routes.take(|r, _| task.hear_route(r))?;
        estimates.take(|e, latency| task.hear_estimate(e, latency))?;
        while let Some(plan) = task.step(context) {
            context.clock.hold(plan.injected_delay_ns);
            plans.send(plan)?;
        }
        // Only every M-th estimate matters: rather than waking for each one (and taking a
        // core from the DFL), expect the next sample's.
        Ok(Next::expect(&*estimates, Some(task.next_due_s())))
    };
    // Asleep for most of `Ts` in real time, the step would start with cold caches: the
    // runtime has the task rehearse again and again until the sample's estimate comes, a
    // dry step if the last one took at most half the longest lead the runtime allows. The
    // step before each rehearsal takes what came, so an estimate that comes during one is
    // the sample's, and ends it.
    let lead_s = WARM_UP_LEAD_TICKS * args.scenario.timing.dt_s();
    let dry_step_max_ns = (0.5 * lead_s * 1e9) as u64;
    let came: ArrivalProbe = {
        let estimates = estimates.clone();
        Rc::new(move || estimates.has_samples())
    };
    let rehearse = |until_ns| task.borrow_mut().rehearse(dry_step_max_ns, until_ns, &came);
    link.run_warming(inputs, &[&plans], step, Some(rehearse))
}
