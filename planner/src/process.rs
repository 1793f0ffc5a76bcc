//! `scmpc planner`: the [`PlannerTask`] as a process: route(k) published for every
//! sample boundary estimate it takes.

use crate::task::PlannerTask;
use protocol::ipc::{ESTIMATE, ROUTE};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError};
use protocol::{Estimate, Role, Route};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let mut task = PlannerTask::new(&args.scenario);
    let link = Link::open(args, Role::Planner)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let routes = link.output::<Route>(ROUTE)?;
    link.run(&[&estimates], &[&routes], |context| {
        estimates.take(|e, _| task.hear_estimate(e))?;
        while let Some(route) = task.step(context) {
            routes.send(route)?;
        }
        // Expect the next sample's estimate rather than wake for every one.
        Ok(Next::expect(&estimates, Some(task.next_due_s())))
    })
}
