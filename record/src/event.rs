//! What happened during a run, one [`Event`] a line of `events.jsonl`.
//!
//! A line is the event's fields, its kind under `event`, the simulated time of the last
//! recorded tick `t` (s) and the wall-clock time since the recorder was created `wall_s`
//! (s), keys in alphabetical order: `{"event":"spawned","host":null,"pid":17058,
//! "role":"plant","t":0.0,"wall_s":0.0318}`. [`EventLine::schema`] is the JSON schema of a
//! line (`scmpc schema`, and `run.mcap`'s `/run/events` channel).

use crate::judge::Outcome;
use protocol::Role;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Every kind of event a run records (docs/running.md, "The run directory").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// A role process was started: its pid, and the host it runs on (none: this one).
    Spawned {
        #[schemars(with = "String")]
        role: Role,
        pid: u32,
        host: Option<String>,
    },
    /// The run's processes are ready, or a restarted or swapped-in process joined.
    Ready(Ready),
    /// Real time: the time of tick 0 on this host's `CLOCK_MONOTONIC`, ns.
    ClockStarted { tick0_monotonic_ns: u64 },
    /// The run's time is up, the robot reached its goal, or its run must abort: it is
    /// braked to rest (by its DFL, or with the DFL lost by its plant's watchdog) before
    /// the processes are stopped.
    BrakingToRest {},
    /// Another host's agent answered and its clock was compared with this one.
    HostJoined {
        host: String,
        endpoint: String,
        agent_pid: u32,
        prefix: String,
        round_trip_us: f64,
        clock_correction_ms: f64,
    },
    /// A host stopped answering; its roles fail over here.
    HostLost {
        host: String,
        #[schemars(with = "Vec<String>")]
        roles: Vec<Role>,
    },
    /// The DFL missed a sample's deadline (docs/design.md, "Timing").
    DeadlineMiss {
        sample: u64,
        /// The plan's solver status, or `missing`.
        status: String,
        production_us: Option<f64>,
        arrival_ms: Option<f64>,
        /// The command mode the DFL fell back to.
        fallback: String,
    },
    /// A tick the record could not write whole: the topics whose sample never came.
    RecordGap { tick: u64, missing: Vec<String> },
    /// The newest command had been applied `plant.command_timeout_s` beyond its own tick:
    /// from this tick the simulated base brakes straight to rest on its own watchdog (ticks in command mode
    /// `watchdog`), until commands come again.
    CommandTimeout { tick: u64 },
    /// A role process died (its exit status) and the iceoryx2 nodes it left were cleaned.
    Crashed {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        status: String,
        nodes_cleaned: usize,
    },
    /// A process's iceoryx2 node was found dead, and its resources cleaned.
    DeadNode {
        node: String,
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        /// The pid of the process killed with it (a wrapper's child), if any.
        child_killed: Option<u32>,
    },
    /// A robot of a fleet held up by another gave way to it, breaking a deadlock
    /// (docs/fleet.md, "Deadlocks"): from this plan's sample on it follows a detour.
    GaveWay { sample: u64, to_robot: u32 },
    /// A role was started anew after a failure.
    Restarted(Restart),
    /// A role whose host was lost was started on this host.
    FailedOver(NewProcess),
    /// In process: a role failed and the run could not go on.
    Aborted {
        #[schemars(with = "String")]
        role: Role,
        reason: String,
    },
    /// A role process stopped writing its inputs' samples (its input timed out).
    InputLost {
        #[schemars(with = "String")]
        role: Role,
        /// The plant's input, for a robot behind a link.
        input: Option<String>,
    },
    /// Samples a consumer refused, by reason (`protocol::Rejection`).
    Rejected {
        consumer: String,
        reason: String,
        count: u64,
    },
    /// A producer whose samples were refused for longer than `limit_s` is treated as
    /// failed.
    RefusedTooLong {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        pid: Option<u32>,
        limit_s: f64,
    },
    /// A replacement process was started for a live swap (docs/running.md, "Swapping").
    SwapStarted {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        replaces: u32,
        pid: u32,
        command: String,
        host: Option<String>,
    },
    /// The replacement is ready: it takes over at `switch_tick`.
    SwapScheduled {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        switch_tick: u64,
    },
    /// The replacement took over and the process it replaced was retired.
    Swapped {
        #[schemars(with = "String")]
        role: Role,
        from_epoch: u32,
        to_epoch: u32,
        old_pid: Option<u32>,
        new_pid: u32,
        /// None: it took over at once, the process it replaced having died.
        switch_tick: Option<u64>,
        how: String,
        warmup_s: f64,
    },
    /// A swap that started did not take over.
    SwapFailed {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        command: String,
        reason: String,
    },
    /// A swap request refused before anything started.
    SwapRefused {
        #[schemars(with = "Option<String>")]
        role: Option<Role>,
        command: String,
        reason: String,
    },
    /// A process that was swapped out exited.
    Retired {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        status: String,
    },
    /// The DFL's safety filter overrode the plan (docs/safety.md).
    SafetyIntervention {
        tick: u64,
        /// `plan_refused`, `committed_unsafe`, `least_unsafe` or `moving_contact`.
        reason: String,
        /// The command mode taken.
        command: String,
        plan_sample: u64,
        /// How far the checked (or chosen) trajectory entered an inflated obstacle, m.
        clearance_m: f64,
        /// The DFL's count so far.
        dfl_count: u32,
    },
    /// The planner found no route from the sample it planned from.
    NoRoute { sample: u64, reason: String },
    /// A new goal, set while the run drives (a live view's client; docs/foxglove.md): in
    /// force from inner tick `from_tick`.
    Goal {
        serial: u32,
        from_tick: u64,
        x: f64,
        y: f64,
        /// The heading to turn to at the goal, rad (none: any).
        heading: Option<f64>,
        /// Who set it: `live`.
        from: String,
    },
    /// A role process exited at the end of the run (`killed`: it had to be).
    Exited {
        #[schemars(with = "String")]
        role: Role,
        epoch: u32,
        status: String,
        killed: bool,
    },
    /// The run ended: its outcome, and the signal that interrupted it.
    End {
        outcome: Outcome,
        signal: Option<String>,
    },
}

/// `ready`: the whole run (its iceoryx2 prefix), or one role that joined it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Ready {
    Run {
        iceoryx2_prefix: String,
    },
    Role {
        #[schemars(with = "String")]
        role: Role,
    },
}

/// `restarted`: a process started with a new epoch, or in process a task made anew after
/// a sample of it was refused.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(untagged)]
pub enum Restart {
    Process(NewProcess),
    InProcess {
        #[schemars(with = "String")]
        role: Role,
        reason: String,
    },
}

/// A role process started with a new epoch, made active at once: its pid, and the host it
/// runs on (none: this one).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct NewProcess {
    #[schemars(with = "String")]
    pub role: Role,
    pub pid: u32,
    pub epoch: u32,
    pub host: Option<String>,
}

impl Event {
    /// Its `event` tag.
    pub fn kind(&self) -> &'static str {
        match self {
            Event::Spawned { .. } => "spawned",
            Event::Ready(_) => "ready",
            Event::ClockStarted { .. } => "clock_started",
            Event::BrakingToRest {} => "braking_to_rest",
            Event::HostJoined { .. } => "host_joined",
            Event::HostLost { .. } => "host_lost",
            Event::DeadlineMiss { .. } => "deadline_miss",
            Event::RecordGap { .. } => "record_gap",
            Event::CommandTimeout { .. } => "command_timeout",
            Event::Crashed { .. } => "crashed",
            Event::DeadNode { .. } => "dead_node",
            Event::GaveWay { .. } => "gave_way",
            Event::Restarted(_) => "restarted",
            Event::FailedOver(_) => "failed_over",
            Event::Aborted { .. } => "aborted",
            Event::InputLost { .. } => "input_lost",
            Event::Rejected { .. } => "rejected",
            Event::RefusedTooLong { .. } => "refused_too_long",
            Event::SwapStarted { .. } => "swap_started",
            Event::SwapScheduled { .. } => "swap_scheduled",
            Event::Swapped { .. } => "swapped",
            Event::SwapFailed { .. } => "swap_failed",
            Event::SwapRefused { .. } => "swap_refused",
            Event::Retired { .. } => "retired",
            Event::SafetyIntervention { .. } => "safety_intervention",
            Event::NoRoute { .. } => "no_route",
            Event::Goal { .. } => "goal",
            Event::Exited { .. } => "exited",
            Event::End { .. } => "end",
        }
    }

    /// Whether it tells of something that went wrong: a warning in `run.mcap`'s log.
    pub fn is_warning(&self) -> bool {
        matches!(
            self,
            Event::DeadlineMiss { .. }
                | Event::SafetyIntervention { .. }
                | Event::Crashed { .. }
                | Event::DeadNode { .. }
                | Event::Restarted(_)
                | Event::FailedOver(_)
                | Event::Aborted { .. }
                | Event::HostLost { .. }
                | Event::InputLost { .. }
                | Event::Rejected { .. }
                | Event::RefusedTooLong { .. }
                | Event::SwapFailed { .. }
                | Event::SwapRefused { .. }
                | Event::NoRoute { .. }
                | Event::RecordGap { .. }
                | Event::CommandTimeout { .. }
        )
    }
}

/// One line of `events.jsonl`: an event and when it was recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
pub struct EventLine {
    /// Wall-clock time since the recorder was created, s.
    pub wall_s: f64,
    /// Simulated time of the last recorded tick, s.
    pub t: f64,
    #[serde(flatten)]
    pub event: Event,
}

impl EventLine {
    /// The line as written: a JSON object, keys in alphabetical order (serde_json's map,
    /// without `preserve_order`, keeps them sorted).
    pub fn to_json(&self) -> serde_json::Result<serde_json::Value> {
        serde_json::to_value(self)
    }

    /// The JSON schema of a line.
    pub fn schema() -> serde_json::Value {
        schemars::schema_for!(EventLine).to_value()
    }
}

#[cfg(test)]
mod tests;
