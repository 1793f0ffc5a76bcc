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
use crate::{PlantKind, Scenario, TIERS_BELOW_TOP};

/// How often a data topic carries a sample. In lockstep the orchestrator waits for a
/// topic it records from its message type ([`Graph::recorded`]) at a `Tick` or `Sample`
/// rate, tick by tick, before it grants the next; at the other rates it records what
/// comes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rate {
    /// Every inner tick (`Ts / M`).
    Tick,
    /// Every MPC sample (`Ts`), stamped with the sample's first tick.
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

/// Calls `$m!` with every data topic: its documentation, its [`crate::Data`] variant, its
/// message type, its topic constant and name and its [`Rate`], in the order of [`TOPICS`].
/// The one list of the data topics: their names ([`crate::topics`]), `Data`, the role
/// processes' ports and the bridges' wire are made from it.
#[macro_export]
macro_rules! data_topics {
    ($m:ident) => {
        $m!(
            /// Noisy output of the plant.
            Measurement(Measurement) = MEASUREMENT "measurement" @ Tick,
            /// True state of the plant (the recorder's; the tracker measures the world at
            /// its ticks).
            Truth(GroundTruth) = TRUTH "truth" @ Tick,
            /// The estimator's extended state.
            Estimate(Estimate) = ESTIMATE "estimate" @ Tick,
            /// The MPC's plan.
            Plan(Plan) = PLAN "plan" @ Sample,
            /// The DFL's command.
            Actuation(Actuation) = ACTUATION "actuation" @ Tick,
            /// The DFL's deadline verdict for every sample.
            Deadline(DeadlineVerdict) = DEADLINE "deadline" @ Verdict,
            /// The planner's route ([`Route`](crate::Route)).
            Route(Route) = ROUTE "route" @ Sample,
            /// The lidar's scans ([`Scan`](crate::Scan)), one every perception tick.
            Scan(Scan) = SCAN "scan" @ PerceptionTick,
            /// The tracker's tracks of the obstacles ([`Tracks`](crate::Tracks)).
            Tracks(Tracks) = TRACKS "tracks" @ PerceptionTick,
            /// The odometer's distance driven ([`Odometry`](crate::Odometry)).
            Odometry(Odometry) = ODOMETRY "odometry" @ Sample,
        );
    };
}

macro_rules! topic_table {
    ($($(#[$doc:meta])* $variant:ident($t:ident) = $topic:ident $name:literal @ $rate:ident),* $(,)?) => {
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
    /// The topics it takes from every other robot of a fleet (docs/fleet.md): its task
    /// names them ([`crate::task::Task::peer_topics`]) when it runs in a fleet.
    pub peer_inputs: &'static [&'static str],
    pub tier: Tier,
    /// Whether the scenario may place it on another host (`[hosts]`, docs/hosts.md).
    pub remote: bool,
    /// Whether it runs only when the scenario names it (`extra_roles`), as an example
    /// role does; the others run whenever their world needs them
    /// ([`Scenario::roles`]).
    pub optional: bool,
    /// Whether, in lockstep, the orchestrator's grant of a tick wakes its process: its
    /// step is due at the tick's time (the plant's). Every other role steps on its inputs,
    /// which the plant's step of the tick sets going, and takes the grant from shared
    /// memory then: not waking it spares the orchestrator a system call a process a tick
    /// (docs/fleet.md, "Measured", "Speed").
    pub woken_by_grants: bool,
    /// Inputs it takes from the tick before the one it steps (the plant and the
    /// estimator: the command of tick `j - 1` at tick `j`). In lockstep each is in shared
    /// memory before the tick is granted, so it need not wake the process
    /// ([`woken_by_grants`](RoleDecl::woken_by_grants)'s reason).
    pub from_the_tick_before: &'static [&'static str],
}

/// A role's `peer_inputs` in [`declare_roles!`]: none unless given.
macro_rules! peer_inputs {
    () => {
        &[]
    };
    ($peer_inputs:expr) => {
        $peer_inputs
    };
}

/// Declares every role once, in data-flow order: its documentation, its code (its index
/// in per-role arrays, [`Control`](crate::Control)'s), its name and its [`RoleDecl`].
/// Makes [`Role`], [`Role::COUNT`], [`Role::ALL`], [`Role::as_str`] and [`ROLES`].
macro_rules! declare_roles {
    ($($(#[$doc:meta])* $role:ident = $code:literal $name:literal {
        inputs: $inputs:expr,
        outputs: $outputs:expr,
        $(peer_inputs: $peer_inputs:expr,)?
        tier: $tier:ident,
        remote: $remote:expr,
        optional: $optional:expr,
        woken_by_grants: $woken_by_grants:expr,
        from_the_tick_before: $from_the_tick_before:expr $(,)?
    }),* $(,)?) => {
        /// The roles of a run ([`declare_roles!`]).
        #[repr(u32)]
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum Role {
            $($(#[$doc])* $role = $code,)*
        }

        impl Role {
            /// How many roles there are (the length of per-role arrays).
            pub const COUNT: usize = [$($code),*].len();
            /// In data-flow order: the in-process executor steps the roles of a tick in it.
            pub const ALL: [Role; Role::COUNT] = [$(Role::$role),*];

            /// Its name: on the command line, in `events.jsonl`, in `SCMPC_ROLE`.
            pub fn as_str(self) -> &'static str {
                match self {
                    $(Role::$role => $name,)*
                }
            }
        }

        /// Every role as the simulated plant's run has it, in [`Role::ALL`] order (the
        /// order of the data within a tick).
        pub const ROLES: [RoleDecl; Role::COUNT] = [
            $(RoleDecl {
                role: Role::$role,
                inputs: $inputs,
                outputs: $outputs,
                peer_inputs: peer_inputs!($($peer_inputs)?),
                tier: Tier::$tier,
                remote: $remote,
                optional: $optional,
                woken_by_grants: $woken_by_grants,
                from_the_tick_before: $from_the_tick_before,
            },)*
        ];
    };
}

declare_roles! {
    /// The simulated robot: the unicycle and its output noise.
    Plant = 0 "plant" {
        inputs: &[ACTUATION],
        outputs: &[TRUTH, MEASUREMENT],
        tier: Control,
        remote: true,
        optional: false,
        woken_by_grants: true,
        from_the_tick_before: &[ACTUATION],
    },
    /// The state estimator: the extended state from the measurements.
    Estimator = 1 "estimator" {
        inputs: &[MEASUREMENT, ACTUATION],
        outputs: &[ESTIMATE],
        tier: Control,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[ACTUATION],
    },
    /// The simulated lidar (docs/running.md, "A lidar"): only in runs with a `[lidar]`.
    Lidar = 7 "lidar" {
        inputs: &[TRUTH],
        outputs: &[SCAN],
        peer_inputs: &[TRUTH],
        tier: Tracking,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
    /// The tracker of the obstacles (docs/running.md, "Moving obstacles"): only in runs
    /// that track an obstacle or see with a lidar. It takes the scans and the estimates
    /// with a lidar, else the truth.
    Tracker = 5 "tracker" {
        inputs: &[SCAN, ESTIMATE, TRUTH],
        outputs: &[TRACKS],
        peer_inputs: &[TRUTH, ESTIMATE, PLAN],
        tier: Tracking,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
    /// The safety-critical linear MPC (or the nonlinear baseline).
    Mpc = 2 "mpc" {
        inputs: &[ESTIMATE, ROUTE, TRACKS],
        outputs: &[PLAN],
        tier: Control,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
    /// The dynamic feedback linearization and its gatekeeper.
    Dfl = 3 "dfl" {
        inputs: &[ESTIMATE, PLAN, TRACKS, SCAN],
        outputs: &[ACTUATION, DEADLINE],
        tier: Control,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
    /// The route planner (docs/planner.md): only in runs that plan routes.
    Planner = 4 "planner" {
        inputs: &[ESTIMATE, TRACKS],
        outputs: &[ROUTE],
        tier: Planning,
        remote: true,
        optional: false,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
    /// The example role (examples/roles/odometer): the distance the estimate has driven,
    /// every sample; only in runs whose `extra_roles` name it.
    Odometer = 6 "odometer" {
        inputs: &[ESTIMATE],
        outputs: &[ODOMETRY],
        tier: Planning,
        remote: false,
        optional: true,
        woken_by_grants: false,
        from_the_tick_before: &[],
    },
}

impl Role {
    pub fn from_code(code: u32) -> Option<Role> {
        Role::ALL.into_iter().find(|r| *r as u32 == code)
    }

    pub fn from_name(name: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.as_str() == name)
    }
}

/// A role is written by its name (`"mpc"`), as in `events.jsonl` and the command line.
impl serde::Serialize for Role {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(self.as_str())
    }
}

impl<'de> serde::Deserialize<'de> for Role {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Role, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(deserializer)?;
        Role::from_name(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("no role is named `{name}`")))
    }
}

/// The plant role played by a ROS 2 robot (`plant.kind = "ros2"`): it takes the commands,
/// and shows the plans, the route and the tracks to RViz.
pub const ROBOT: RoleDecl = RoleDecl {
    role: Role::Plant,
    inputs: &[ACTUATION, PLAN, ROUTE, TRACKS],
    outputs: &[TRUTH, MEASUREMENT],
    peer_inputs: &[],
    tier: Tier::Control,
    remote: true,
    optional: false,
    woken_by_grants: true,
    from_the_tick_before: &[],
};

/// The declaration of `role` in a run whose plant is `plant`.
pub fn declaration(role: Role, plant: PlantKind) -> &'static RoleDecl {
    match (role, plant) {
        (Role::Plant, PlantKind::Ros2) => &ROBOT,
        _ => &ROLES[Role::ALL.iter().position(|r| *r == role).unwrap_or(0)],
    }
}

/// The topics `role` takes from every other robot of a fleet ([`RoleDecl::peer_inputs`]).
pub fn peer_inputs_of(role: Role) -> &'static [&'static str] {
    declaration(role, PlantKind::Sim).peer_inputs
}

/// The tick topics whose samples at sample starts (ticks that are multiples of `M`) are
/// announced on an event service of their own as well (`runtime::ipc::Topic`): a role
/// that steps on them only then ([`crate::task::Task::woken_at_sample_starts`]) is, in
/// lockstep, woken once a sample by them rather than every tick (docs/fleet.md, "Speed").
pub const SAMPLE_START_TOPICS: &[&str] = &[TRUTH, ESTIMATE];

/// How many roles of a robot take `topic` from each other robot of a fleet (their
/// [`RoleDecl::peer_inputs`]).
pub fn peer_takers_of(topic: &str) -> usize {
    (ROLES.iter())
        .filter(|r| r.peer_inputs.contains(&topic))
        .count()
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

    /// The data topics of this run the record has no place of its own for and writes from
    /// what their message type names ([`crate::Message::RECORDED`]).
    pub fn recorded(&self) -> impl Iterator<Item = &'static Topic> + '_ {
        TOPICS.iter().filter(|t| {
            producer_of(t.name).is_some_and(|p| self.runs(p))
                && !crate::Data::recorded_names(t.name).is_empty()
        })
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
    fn role_codes_index_per_role_arrays_once_each_and_names_are_distinct() {
        let mut codes: Vec<usize> = Role::ALL.iter().map(|r| *r as usize).collect();
        codes.sort_unstable();
        assert_eq!(codes, (0..Role::COUNT).collect::<Vec<_>>());
        for role in Role::ALL {
            assert_eq!(Role::from_name(role.as_str()), Some(role));
            assert_eq!(Role::from_code(role as u32), Some(role));
        }
    }

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
