//! `scmpc estimator`: the [`EstimatorTask`] as a process: every measurement estimated, in
//! order, and published.

use crate::task::EstimatorTask;
use protocol::ipc::{ACTUATION, ESTIMATE, MEASUREMENT};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError};
use protocol::{Actuation, Estimate, Measurement, Role};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Estimator)?;
    let measurements = link.input::<Measurement>(MEASUREMENT, Role::Plant)?;
    let actuation = link.input::<Actuation>(ACTUATION, Role::Dfl)?;
    let estimates = link.output::<Estimate>(ESTIMATE)?;
    let mut task = EstimatorTask::new(&args.scenario, args.epoch);
    link.run(&[&measurements, &actuation], &[&estimates], |context| {
        // The periodic input first: its receipt time is the hop latency.
        measurements.take(|m, latency| task.hear_measurement(m, latency))?;
        actuation.take(|a, _| task.hear_actuation(a))?;
        while let Some(estimate) = task.step(context) {
            // A slow estimator (`fault.estimator_delay_ms`), in any clock: in lockstep only
            // the wall time grows.
            std::thread::sleep(task.publish_delay());
            estimates.send(estimate)?;
        }
        Ok(Next::expect(&measurements, task.next_due_s()))
    })
}
