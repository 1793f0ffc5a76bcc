//! The graph of a run, declared once (docs/design.md, "Roles and tasks"): each role's
//! inputs and outputs, its real-time tier and whether it may run on another host
//! ([`ROLES`], and [`ROBOT`] for the plant role played by a ROS 2 robot); each data
//! topic's message type and rate ([`crate::data_topics!`], [`TOPICS`]).
//!
//! Everything that wires roles is derived from it: which role produces a topic and which
//! take it ([`Graph`], for the roles a scenario runs), where an output sits in the
//! publishers a producer announces ([`output_slot`]), the topics a process opens, the
//! in-process executor's hand-over, the bridges' routes between hosts and the tiers.

use crate::topics::*;
use crate::{PlantKind, Role, Scenario, TIERS_BELOW_TOP};

/// How often a data topic carries a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rate {
    /// Every inner tick (`Ts / M`).
    Tick,
    /// Every MPC sample (`Ts`).
    Sample,
    /// Every perception tick (`perception.period_s`).
    PerceptionTick,
    /// When the producer judges a sample (the DFL's verdict on sample k, at k + 1).
    Verdict,
}

impl Rate {
    pub fn as_str(self) -> &'static str {
        match self {
            Rate::Tick => "tick",
            Rate::Sample => "sample",
            Rate::PerceptionTick => "perception_tick",
            Rate::Verdict => "verdict",
        }
    }
}

/// A data topic: its name, the iceoryx2 type name of its messages (`scmpc schema`'s
/// `services` and `types`), its rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Topic {
    pub name: &'static str,
    pub message: &'static str,
    pub rate: Rate,
}

/// Calls `$m!` with every data topic: its [`crate::Data`] variant, its message type, its
/// topic constant and its [`Rate`], in the order of [`TOPICS`]. The one list of the data
/// topics' types: `Data`, the role processes' ports and the bridges' wire are made from it.
#[macro_export]
macro_rules! data_topics {
    ($m:ident) => {
        $m!(
            Measurement(Measurement) = MEASUREMENT @ Tick,
            Truth(GroundTruth) = TRUTH @ Tick,
            Estimate(Estimate) = ESTIMATE @ Tick,
            Plan(Plan) = PLAN @ Sample,
            Actuation(Actuation) = ACTUATION @ Tick,
            Deadline(DeadlineVerdict) = DEADLINE @ Verdict,
            Route(Route) = ROUTE @ Sample,
            Tracks(Tracks) = TRACKS @ PerceptionTick,
        );
    };
}

macro_rules! topic_table {
    ($($variant:ident($t:ident) = $topic:ident @ $rate:ident),* $(,)?) => {
        /// Every data topic ([`data_topics!`](crate::data_topics)).
        pub const TOPICS: &[Topic] = &[
            $(Topic {
                name: $topic,
                message: concat!("scmpc::", stringify!($t)),
                rate: Rate::$rate,
            },)*
        ];
    };
}
data_topics!(topic_table);

/// A process's place in the data path; the higher, the earlier it runs on a shared core
/// (`runtime::realtime`).
///
/// The control loop shares one tier, as measured on an idle two-core machine (10 s paper
/// runs, three against three without the policy; docs/performance.md, "Real time under
/// load"): with the MPC one tier below the DFL, the DFL, woken by the estimate the MPC
/// solves from, preempted the solve, and the MPC step p50 rose from 33-42 to 50-63 µs;
/// with the estimator one tier below the plant, the plant's wake-up preempted the estimator
/// polling for the measurement on the same core, and that hop's p50 rose from 7 to 11-21
/// µs. In one tier, the kernel wakes each of them on a core that runs none of the others.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Tier {
    /// The orchestrator's recording.
    Recording,
    /// The route planner.
    Planning,
    /// The tracker of moving obstacles.
    Tracking,
    /// The plant (or the ROS 2 robot), the estimator, the MPC and the DFL.
    Control,
}

impl Tier {
    /// The tier of `role`'s process ([`RoleDecl::tier`]).
    pub fn of(role: Role) -> Tier {
        declaration(role, PlantKind::Sim).tier
    }

    /// Its `SCHED_FIFO` priority when the top tier has `top`.
    pub fn priority(self, top: u8) -> u8 {
        let below = match self {
            Tier::Control => 0,
            Tier::Tracking => 1,
            Tier::Planning => 2,
            Tier::Recording => TIERS_BELOW_TOP,
        };
        top - below
    }
}

/// What a role is, as far as wiring goes: the one declaration of it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RoleDecl {
    pub role: Role,
    /// The topics it may take, its periodic input (the one `Due::Expect` names) first. A
    /// process opens those whose producer runs in the scenario and its task takes
    /// ([`crate::task::Task::takes`]).
    pub inputs: &'static [&'static str],
    /// The topics it publishes, in the order of the publishers it announces when it joins
    /// ([`output_slot`]).
    pub outputs: &'static [&'static str],
    pub tier: Tier,
    /// Whether the scenario may place it on another host (`[hosts]`, docs/hosts.md).
    pub remote: bool,
}

/// Every role as the simulated plant's run has it, in [`Role::ALL`] order (the order of
/// the data within a tick).
pub const ROLES: [RoleDecl; Role::COUNT] = [
    RoleDecl {
        role: Role::Plant,
        inputs: &[ACTUATION],
        outputs: &[TRUTH, MEASUREMENT],
        tier: Tier::Control,
        remote: true,
    },
    RoleDecl {
        role: Role::Estimator,
        inputs: &[MEASUREMENT, ACTUATION],
        outputs: &[ESTIMATE],
        tier: Tier::Control,
        remote: true,
    },
    RoleDecl {
        role: Role::Tracker,
        inputs: &[TRUTH],
        outputs: &[TRACKS],
        tier: Tier::Tracking,
        remote: true,
    },
    RoleDecl {
        role: Role::Mpc,
        inputs: &[ESTIMATE, ROUTE, TRACKS],
        outputs: &[PLAN],
        tier: Tier::Control,
        remote: true,
    },
    RoleDecl {
        role: Role::Dfl,
        inputs: &[ESTIMATE, PLAN, TRACKS],
        outputs: &[ACTUATION, DEADLINE],
        tier: Tier::Control,
        remote: true,
    },
    RoleDecl {
        role: Role::Planner,
        inputs: &[ESTIMATE],
        outputs: &[ROUTE],
        tier: Tier::Planning,
        remote: true,
    },
];

/// The plant role played by a ROS 2 robot (`plant.kind = "ros2"`): it takes the commands,
/// and shows the plans, the route and the tracks to RViz.
pub const ROBOT: RoleDecl = RoleDecl {
    role: Role::Plant,
    inputs: &[ACTUATION, PLAN, ROUTE, TRACKS],
    outputs: &[TRUTH, MEASUREMENT],
    tier: Tier::Control,
    remote: true,
};

/// The declaration of `role` in a run whose plant is `plant`.
pub fn declaration(role: Role, plant: PlantKind) -> &'static RoleDecl {
    match (role, plant) {
        (Role::Plant, PlantKind::Ros2) => &ROBOT,
        _ => &ROLES[Role::ALL.iter().position(|r| *r == role).unwrap_or(0)],
    }
}

/// The role that produces data topic `topic`.
pub fn producer_of(topic: &str) -> Option<Role> {
    ROLES
        .iter()
        .find(|d| d.outputs.contains(&topic))
        .map(|d| d.role)
}

/// Where output `topic` of `producer` sits in the publishers it announces when it joins
/// ([`Status::publishers`](crate::Status::publishers)); `None`: not one of its outputs.
pub fn output_slot(producer: Role, topic: &str) -> Option<usize> {
    declaration(producer, PlantKind::Sim)
        .outputs
        .iter()
        .position(|t| *t == topic)
}

/// The output topic of `producer` in publisher slot `slot` ([`output_slot`]).
pub fn output_topic(producer: Role, slot: usize) -> Option<&'static str> {
    declaration(producer, PlantKind::Sim)
        .outputs
        .get(slot)
        .copied()
}

/// The graph of the roles a scenario runs: who takes what.
#[derive(Debug, Clone)]
pub struct Graph {
    roles: Vec<&'static RoleDecl>,
}

impl Graph {
    /// The graph of `scenario`'s roles ([`Scenario::roles`]).
    pub fn of(scenario: &Scenario) -> Graph {
        let roles: Vec<Role> = scenario.roles().collect();
        Graph::of_roles(&roles, scenario.plant.kind)
    }

    /// The graph of `roles`, in a run whose plant is `plant`.
    pub fn of_roles(roles: &[Role], plant: PlantKind) -> Graph {
        Graph {
            roles: roles.iter().map(|&r| declaration(r, plant)).collect(),
        }
    }

    /// Whether `role` runs.
    pub fn runs(&self, role: Role) -> bool {
        self.roles.iter().any(|d| d.role == role)
    }

    /// The declaration of `role` in this run.
    pub fn declaration(&self, role: Role) -> Option<&'static RoleDecl> {
        self.roles.iter().find(|d| d.role == role).copied()
    }

    /// The topics `role` may take in this run: its declared inputs whose producer runs,
    /// in its declared order.
    pub fn inputs_of(&self, role: Role) -> impl Iterator<Item = &'static str> + '_ {
        let inputs = self.declaration(role).map_or(&[][..], |d| d.inputs);
        inputs
            .iter()
            .copied()
            .filter(|t| producer_of(t).is_some_and(|p| self.runs(p)))
    }

    /// The roles that may take `topic` in this run.
    pub fn consumers_of<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = Role> + 'a {
        self.roles
            .iter()
            .filter(move |d| self.inputs_of(d.role).any(|t| t == topic))
            .map(|d| d.role)
    }

    /// Every data topic a role of this run produces, with its producer.
    pub fn topics(&self) -> impl Iterator<Item = (&'static str, Role)> + '_ {
        TOPICS
            .iter()
            .filter_map(|t| Some((t.name, producer_of(t.name)?)))
            .filter(|(_, p)| self.runs(*p))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_topic_has_one_producer_and_every_declared_topic_is_a_data_topic() {
        for topic in TOPICS {
            let producers = ROLES.iter().filter(|d| d.outputs.contains(&topic.name));
            assert_eq!(producers.count(), 1, "{}", topic.name);
        }
        for d in ROLES.iter().chain([&ROBOT]) {
            for t in d.inputs.iter().chain(d.outputs) {
                assert!(TOPICS.iter().any(|topic| topic.name == *t), "{t}");
            }
        }
        assert_eq!(ROBOT.outputs, ROLES[0].outputs, "the robot plays the plant");
        let order: Vec<Role> = ROLES.iter().map(|d| d.role).collect();
        assert_eq!(order, Role::ALL);
    }

    #[test]
    fn a_run_takes_only_what_its_roles_produce_and_the_robot_takes_the_plans() {
        let paper = Scenario::default();
        let graph = Graph::of(&paper);
        assert!(!graph.runs(Role::Planner) && !graph.runs(Role::Tracker));
        assert_eq!(graph.inputs_of(Role::Mpc).collect::<Vec<_>>(), [ESTIMATE]);
        assert_eq!(graph.consumers_of(PLAN).collect::<Vec<_>>(), [Role::Dfl]);
        assert_eq!(
            graph.topics().count(),
            6,
            "all but the route and the tracks"
        );
        let robot = Scenario {
            plant: crate::PlantConfig {
                kind: PlantKind::Ros2,
                ..paper.plant.clone()
            },
            ..paper
        };
        let graph = Graph::of(&robot);
        assert_eq!(
            graph.consumers_of(PLAN).collect::<Vec<_>>(),
            [Role::Plant, Role::Dfl]
        );
        assert_eq!(
            graph.inputs_of(Role::Plant).collect::<Vec<_>>(),
            [ACTUATION, PLAN]
        );
    }

    #[test]
    fn slots_follow_the_declared_outputs() {
        assert_eq!(output_slot(Role::Dfl, ACTUATION), Some(0));
        assert_eq!(output_slot(Role::Dfl, DEADLINE), Some(1));
        assert_eq!(output_slot(Role::Plant, MEASUREMENT), Some(1));
        assert_eq!(output_slot(Role::Mpc, ESTIMATE), None);
        assert_eq!(output_topic(Role::Plant, 0), Some(TRUTH));
        assert_eq!(output_topic(Role::Planner, 1), None);
    }
}
