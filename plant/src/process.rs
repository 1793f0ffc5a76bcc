//! `scmpc plant`: the [`PlantTask`] as a process. Each tick it integrates the actuation
//! heard for the tick before and publishes the truth and the measurement, when the run's
//! clock reaches the tick (a grant in lockstep, the wall clock in real time).

use crate::task::PlantTask;
use protocol::ipc::{ACTUATION, MEASUREMENT, TRUTH};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError};
use protocol::{Actuation, GroundTruth, Measurement, Role};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Plant)?;
    let measurement = link.output::<Measurement>(MEASUREMENT)?;
    let truth = link.output::<GroundTruth>(TRUTH)?;
    let actuation = link.input::<Actuation>(ACTUATION, Role::Dfl)?;
    let mut task = PlantTask::new(&args.scenario);
    link.run(&[&actuation], &[&truth, &measurement], |context| {
        actuation.take(|a, _| task.hear(a))?;
        while let Some((t, m)) = task.step(context) {
            truth.send(t)?;
            measurement.send(m)?;
        }
        Ok(Next::At(task.next_due_s()))
    })
}
