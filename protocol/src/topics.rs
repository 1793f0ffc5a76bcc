//! The topics of a run and its data flow: which role produces each data topic and which
//! roles take it (docs/design.md). Every executor wires roles by this table: the process
//! runtime opens a role's inputs and outputs by it, a bridge between hosts carries a topic
//! to every host with a role that takes it, the in-process executor hands each output to
//! the tasks that take it.

/// Noisy output of the plant.
pub const MEASUREMENT: &str = "measurement";
/// True state of the plant (the recorder's; the tracker measures the world at its ticks).
pub const TRUTH: &str = "truth";
pub const ESTIMATE: &str = "estimate";
pub const PLAN: &str = "plan";
pub const ACTUATION: &str = "actuation";
/// The DFL's deadline verdict for every sample.
pub const DEADLINE: &str = "deadline";
/// The planner's route ([`Route`](crate::Route)).
pub const ROUTE: &str = "route";
/// The tracker's tracks of the obstacles ([`Tracks`](crate::Tracks)).
pub const TRACKS: &str = "tracks";
/// Orchestrator to processes: clock grants, start, stop.
pub const CONTROL: &str = "control";
/// Processes to orchestrator: ready, input lost.
pub const STATUS: &str = "status";
/// `scmpc swap` to orchestrator: live swap requests.
pub const SWAP: &str = "swap";
/// Orchestrator to `scmpc swap`: how a requested swap ended.
pub const SWAP_REPLY: &str = "swap_reply";

/// The data flow (docs/design.md): each data topic, the role that produces it and the
/// roles that take it (the orchestrator records every topic). The role processes open
/// these inputs; a bridge between hosts carries a topic to every host with a role that
/// takes it.
pub const DATA_FLOW: [(&str, crate::Role, &[crate::Role]); 8] = {
    use crate::Role::*;
    [
        (MEASUREMENT, Plant, &[Estimator]),
        (TRUTH, Plant, &[Tracker]),
        (ESTIMATE, Estimator, &[Mpc, Dfl, Planner]),
        (PLAN, Mpc, &[Dfl]),
        (ACTUATION, Dfl, &[Plant, Estimator]),
        (DEADLINE, Dfl, &[]),
        (ROUTE, Planner, &[Mpc]),
        (TRACKS, Tracker, &[Mpc, Dfl]),
    ]
};

/// The role that produces data topic `topic`.
pub fn producer_of(topic: &str) -> Option<crate::Role> {
    DATA_FLOW
        .iter()
        .find(|(t, _, _)| *t == topic)
        .map(|(_, producer, _)| *producer)
}

/// The output topic of `producer` in publisher slot `slot` ([`output_slot`]).
pub fn output_topic(producer: crate::Role, slot: usize) -> Option<&'static str> {
    DATA_FLOW
        .iter()
        .map(|(t, _, _)| *t)
        .find(|t| output_slot(producer, t) == Some(slot))
}

/// Where output `topic` of `producer` sits in the publishers it announces when it joins
/// ([`Status::publishers`](crate::Status::publishers)); `None`: not one of its outputs.
pub fn output_slot(producer: crate::Role, topic: &str) -> Option<usize> {
    use crate::Role;
    match (producer, topic) {
        (Role::Plant, TRUTH) | (Role::Estimator, ESTIMATE) | (Role::Mpc, PLAN) => Some(0),
        (Role::Dfl, ACTUATION) | (Role::Planner, ROUTE) | (Role::Tracker, TRACKS) => Some(0),
        (Role::Plant, MEASUREMENT) | (Role::Dfl, DEADLINE) => Some(1),
        _ => None,
    }
}
