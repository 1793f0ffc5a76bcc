//! What the orchestrator and a host's agent tell each other, as JSON over Zenoh queries
//! (requests answered by one reply) and publications (the agent's exit reports).

use crate::HostError;
use crate::LinkCounters;
use crate::clock_sync::ClockLink;
use serde::{Deserialize, Serialize, de::DeserializeOwned};
use std::time::Duration;
use zenoh::Wait;

/// The orchestrator asks an agent to join a run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct JoinRequest {
    /// The run's key chunk ([`crate::keys::run_of_prefix`]; a fleet's robot's own,
    /// [`crate::keys::fleet_robot_run`]).
    pub run: String,
    /// The run id every sample carries (`runtime::ipc::run_id` of the run's prefix).
    pub run_id: u32,
    /// The run's key (hexadecimal, [`crate::auth::RunKey`]).
    pub key: String,
    /// The host's name, as the scenario places roles on it.
    pub host: String,
    /// `lockstep` or `realtime`.
    pub mode: String,
    /// The robot whose pipeline the host's roles are part of.
    pub robot: u32,
    /// The validated scenario, every key spelled out.
    pub scenario_toml: String,
    /// The roles placed on the host.
    pub roles: Vec<String>,
    /// Topics the host's bridge sends to the orchestrator's host.
    pub send: Vec<String>,
    /// Topics it receives.
    pub receive: Vec<String>,
    /// The other robots' topics it receives (a fleet's robot, docs/fleet.md), by robot
    /// and topic.
    #[serde(default)]
    pub peer_receive: Vec<(u32, String)>,
}

/// An agent's answer to a join request.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct JoinReply {
    /// Empty when the host joined; else why not.
    pub error: String,
    pub agent_pid: u32,
    /// The host's iceoryx2 prefix for the run.
    pub prefix: String,
    /// The host's clock against the orchestrator's.
    pub clock: ClockLink,
}

/// A command of the orchestrator to an agent, for a run it joined.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub enum HostCommand {
    /// Start `command` (empty: the built-in process) as `role` with producer `epoch`.
    Spawn {
        role: String,
        epoch: u32,
        command: Vec<String>,
    },
    /// SIGTERM the process of `role` and `epoch` (it leaves its loop and exits).
    Terminate { role: String, epoch: u32 },
    /// SIGKILL it.
    Kill { role: String, epoch: u32 },
    /// The run has ended: stop every role process, remove the run's resources.
    End,
}

/// An agent's answer to a command.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct CommandReply {
    /// Empty when done; else why not.
    pub error: String,
    /// The pid of a process started or signalled.
    pub pid: u32,
    /// On `End`: what the host's bridge carried.
    pub link: LinkCounters,
}

/// An agent's report of a role process that exited.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Exit {
    pub role: String,
    pub epoch: u32,
    pub pid: u32,
    pub status: String,
}

/// Sends `request` on `key` and returns the first reply, within `timeout`.
pub fn ask<Q: Serialize, R: DeserializeOwned>(
    session: &zenoh::Session,
    key: &str,
    request: &Q,
    timeout: Duration,
) -> Result<R, HostError> {
    let payload = serde_json::to_vec(request).map_err(|e| HostError::Protocol(e.to_string()))?;
    let replies = session
        .get(key)
        .payload(payload)
        .timeout(timeout)
        .wait()
        .map_err(|e| HostError::Zenoh(format!("asking {key}: {e}")))?;
    let reply = replies
        .recv()
        .map_err(|_| HostError::Protocol(format!("no answer on {key} within {timeout:?}")))?;
    let sample = reply
        .result()
        .map_err(|e| HostError::Protocol(format!("{key}: {:?}", e.payload().to_bytes())))?;
    serde_json::from_slice(&sample.payload().to_bytes())
        .map_err(|e| HostError::Protocol(format!("{key}: an answer that is not one: {e}")))
}

/// The request a query carries.
pub fn request_of<Q: DeserializeOwned>(query: &zenoh::query::Query) -> Result<Q, String> {
    let bytes = query
        .payload()
        .map(|p| p.to_bytes().to_vec())
        .unwrap_or_default();
    serde_json::from_slice(&bytes).map_err(|e| format!("a request that is not one: {e}"))
}

/// Answers `query` with `reply`, and ends it (a query's asker waits for its end).
pub fn answer<R: Serialize>(query: zenoh::query::Query, reply: &R) {
    if let Ok(bytes) = serde_json::to_vec(reply) {
        let _ = query.reply(query.key_expr().clone(), bytes).wait();
    }
}
