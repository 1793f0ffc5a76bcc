//! The Zenoh key expressions of scmpc. An agent answers on its host's key; everything of a
//! run is under the run's key (the orchestrator's iceoryx2 prefix), so runs never meet.

/// The name the orchestrator's host goes by in keys (refused as a host name).
pub const ORCHESTRATOR: &str = protocol::endpoint::ORCHESTRATOR_HOST;

/// Where the agent of `host` takes join requests.
pub fn agent_join(host: &str) -> String {
    format!("scmpc/agent/{host}/join")
}

/// Samples of robot `robot`'s `topic` for `host` in `run` (`topic` may be `*`).
pub fn to_host(run: &str, host: &str, robot: u32, topic: &str) -> String {
    format!("scmpc/run/{run}/to/{host}/robot{robot}/{topic}")
}

/// Samples of every robot's topics for `host` in `run`: a fleet's robot's bridge takes
/// the other robots' too. Each robot of a fleet has a run key of its own
/// ([`fleet_robot_run`]), so only its own bridge's samples come here, also when two
/// robots share a host.
pub fn to_host_all(run: &str, host: &str) -> String {
    format!("scmpc/run/{run}/to/{host}/**")
}

/// The robot and the topic of a key of [`to_host`].
pub fn robot_topic_of(key: &str) -> Option<(u32, &str)> {
    let mut chunks = key.rsplit('/');
    let topic = chunks.next()?;
    let robot = chunks.next()?.strip_prefix("robot")?.parse().ok()?;
    Some((robot, topic))
}

/// Where the agent of `host` takes the orchestrator's commands for `run`.
pub fn host_command(run: &str, host: &str) -> String {
    format!("scmpc/run/{run}/host/{host}/command")
}

/// Where the agent of `host` reports its role processes' exits in `run`.
pub fn host_exits(run: &str, host: &str) -> String {
    format!("scmpc/run/{run}/host/{host}/exit")
}

/// The orchestrator's clock in `run`: a query is answered with its time.
pub fn clock(run: &str) -> String {
    format!("scmpc/run/{run}/clock")
}

/// The liveliness token of `who` (a host, or [`ORCHESTRATOR`]) in `run`.
pub fn alive(run: &str, who: &str) -> String {
    format!("scmpc/run/{run}/alive/{who}")
}

/// The liveliness tokens of every host in `run`.
pub fn alive_all(run: &str) -> String {
    format!("scmpc/run/{run}/alive/*")
}

/// The key chunk of robot `robot`'s part of a fleet's run on `prefix`: each robot's links
/// to other hosts are under a run key of their own, so that two robots on one host (a join,
/// a bridge and processes each) never take each other's samples, commands or exits.
pub fn fleet_robot_run(prefix: &str, robot: u32) -> String {
    format!("{}-robot{robot}", run_of_prefix(prefix))
}

/// The zenoh key chunk of a run: its iceoryx2 prefix without what keys do not allow.
pub fn run_of_prefix(prefix: &str) -> String {
    prefix
        .chars()
        .filter(|c| c.is_ascii_alphanumeric() || *c == '-' || *c == '_')
        .collect()
}
