//! The names of a run's topics. Which role produces each data topic and which take it is
//! the declared graph's ([`crate::graph`]).

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

pub use crate::graph::{output_slot, output_topic, producer_of};
