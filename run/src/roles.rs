//! Every role `scmpc` runs, and its task: the one place a role is registered. Adding a
//! role is a crate with its [`Task`], its declaration ([`protocol::graph`]), and a line in
//! [`roles!`] below; both executors then run it (docs/design.md, "Roles and tasks").

use crate::closed_loop::Stepped;
use protocol::task::{Resources, Task, TaskError};
use protocol::{Role, Validated};
use runtime::process::{ProcessArgs, ProcessError};

/// Declares, for every role, how a process of it runs ([`serve`]) and how the in-process
/// executor makes its task ([`in_process`]).
macro_rules! roles {
    ($($role:ident => $task:ty),* $(,)?) => {
        /// Every role registered, in the order of the data within a tick.
        pub const ALL: &[Role] = &[$(Role::$role),*];

        /// Runs a process of `role` until the orchestrator stops it ([`runtime::serve`]);
        /// the plant of `plant.kind = "ros2"` is a ROS 2 robot ([`robot::RobotTask`]),
        /// and its lidar the robot's ([`robot::ScanTask`]).
        pub fn serve(role: Role, args: &ProcessArgs) -> Result<(), ProcessError> {
            if args.scenario.plant.kind == protocol::PlantKind::Ros2 {
                match role {
                    Role::Plant => return runtime::serve::<robot::RobotTask>(args),
                    Role::Lidar => return runtime::serve::<robot::ScanTask>(args),
                    _ => {}
                }
            }
            match role {
                $(Role::$role => runtime::serve::<$task>(args),)*
            }
        }

        /// The task of `role` for the in-process executor, with producer epoch `epoch`.
        pub fn in_process(
            role: Role,
            scenario: &Validated,
            epoch: u32,
        ) -> Result<Box<dyn Stepped>, TaskError> {
            if role == Role::Plant && scenario.plant.kind == protocol::PlantKind::Ros2 {
                return Err(TaskError::setup(Role::Plant, RobotInProcess));
            }
            match role {
                $(Role::$role => {
                    let resources = <$task as Task>::Resources::open(scenario)?;
                    Ok(Box::new(<$task as Task>::new(scenario, epoch, resources)?))
                })*
            }
        }
    };
}

/// A ROS 2 robot asked of the in-process executor.
#[derive(Debug, thiserror::Error)]
#[error("plant.kind = \"ros2\": a robot is driven in real time only (scmpc run --mode realtime)")]
pub struct RobotInProcess;

roles! {
    Plant => plant::PlantTask,
    Lidar => lidar::LidarTask,
    Estimator => estimator::EstimatorTask,
    Tracker => tracker::TrackerTask,
    Mpc => mpc::MpcTask,
    Dfl => dfl::DflTask,
    Planner => planner::PlannerTask,
    Odometer => odometer::OdometerTask,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::closed_loop::ClosedLoop;

    #[test]
    fn every_task_takes_and_gives_only_the_topics_its_role_declares() {
        use protocol::PlantKind;
        use protocol::graph::declaration;
        // The unmapped world runs every role of the simulated plant, with the optional ones.
        let optional: Vec<&str> = (Role::ALL.iter())
            .filter(|r| declaration(**r, PlantKind::Sim).optional)
            .map(|r| r.as_str())
            .collect();
        let extra = format!("extra_roles={optional:?}");
        let scenario = crate::scenarios::load(Some("unmapped"), &[extra]).unwrap();
        assert_eq!(scenario.roles().count(), Role::COUNT);
        for role in scenario.roles() {
            let task = in_process(role, &scenario, 0).unwrap();
            let inputs = declaration(role, PlantKind::Sim).inputs;
            for data in protocol::Data::one_of_each() {
                assert_eq!(
                    task.accepts(data),
                    inputs.contains(&data.topic()),
                    "the {} and `{}`",
                    role.as_str(),
                    data.topic()
                );
            }
        }
        // What each gives: the loop ends a run on a message its role does not declare.
        let mut closed_loop = ClosedLoop::new(&scenario).unwrap();
        while !closed_loop.is_done() {
            closed_loop.step().unwrap();
        }
    }

    #[test]
    fn a_task_that_cannot_be_made_keeps_its_roles_error_with_its_type_to_the_exit_message() {
        let scenario = crate::scenarios::load(None, &["plant.kind=ros2".into()]).unwrap();
        let Err(error) = ClosedLoop::new(&scenario) else {
            panic!("a robot stepped in process");
        };
        let error = anyhow::Error::from(error);
        let task = error.downcast_ref::<TaskError>().unwrap();
        assert_eq!(task.role(), Role::Plant);
        assert!(matches!(task, TaskError::Setup { .. }));
        assert!(error.chain().any(|e| e.is::<RobotInProcess>()));
        assert_eq!(
            format!("{error:#}"),
            format!("setting up the plant: {RobotInProcess}")
        );
    }
}
