//! The names of a run's topics (the data topics' from [`crate::data_topics!`]). Which role produces each data topic and which take it is
//! the declared graph's ([`crate::graph`]).

macro_rules! topic_names {
    ($($(#[$doc:meta])* $variant:ident($t:ident) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
        $($(#[$doc])* pub const $topic: &str = $name;)*
    };
}
crate::data_topics!(topic_names);

/// Orchestrator to processes: clock grants, start, stop.
pub const CONTROL: &str = "control";
/// Processes to orchestrator: ready, input lost.
pub const STATUS: &str = "status";
/// `scmpc swap` to orchestrator: live swap requests.
pub const SWAP: &str = "swap";
/// Orchestrator to `scmpc swap`: how a requested swap ended.
pub const SWAP_REPLY: &str = "swap_reply";
/// The topics of the run itself, no robot's: their services keep their bare names.
pub const RUN_TOPICS: [&str; 2] = [SWAP, SWAP_REPLY];

pub use crate::graph::{output_slot, output_topic, producer_of};

/// The iceoryx2 service name of `topic` of robot `robot`: the robot's pipeline (its data
/// topics, its control and its status) is under `robot<id>/`, so two robots' pipelines
/// on one host never share a service (docs/design.md, "Roles and tasks", role instances).
/// What is the run's and no robot's ([`SWAP`], [`SWAP_REPLY`]) keeps its bare name.
pub fn service_name(robot: u32, topic: &str) -> String {
    format!("robot{robot}/{topic}")
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_robots_service_names_carry_its_id_and_differ_from_anothers() {
        assert_eq!(super::service_name(0, super::PLAN), "robot0/plan");
        assert_ne!(
            super::service_name(0, super::CONTROL),
            super::service_name(1, super::CONTROL)
        );
    }
}
