//! `scmpc dfl`: the [`DflTask`] as a process: a command (and on a sample boundary the
//! deadline verdict) published for every estimate, and brakes of its own while the
//! estimator is silent.

use crate::task::DflTask;
use protocol::ipc::{ACTUATION, DEADLINE, ESTIMATE, PLAN};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError};
use protocol::{Actuation, DeadlineVerdict, Estimate, Plan, Role};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Dfl)?;
    let estimates = link.input::<Estimate>(ESTIMATE, Role::Estimator)?;
    let plans = link.input::<Plan>(PLAN, Role::Mpc)?;
    let actuation = link.output::<Actuation>(ACTUATION)?;
    let deadlines = link.output::<DeadlineVerdict>(DEADLINE)?;
    let mut task = DflTask::new(&args.scenario);
    link.run(
        &[&estimates, &plans],
        &[&actuation, &deadlines],
        |context| {
            // The periodic input first: its receipt time is the hop latency.
            estimates.take(|e, latency| task.hear_estimate(e, latency))?;
            plans.take(|p, _| task.hear_plan(&p, context))?;
            while let Some((command, verdict)) = task.step(context) {
                if let Some(verdict) = verdict {
                    deadlines.send(verdict)?;
                }
                actuation.send(command)?;
            }
            if let Some(brake) = task.brake_if_silent(context) {
                actuation.send(brake)?;
            }
            // No scheduled spin here (unlike the estimator): on two cores a third spinning
            // process starves the plant and the estimator (measured: docs/performance.md).
            Ok(Next::Wait(task.next_wake_s()))
        },
    )
}
