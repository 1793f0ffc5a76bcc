//! `[live]`: the run served to Foxglove while it drives (docs/foxglove.md, "Live").
//!
//! How a run is watched is not part of the experiment: the section is never written out
//! ([`Scenario::to_toml`](crate::Scenario::to_toml) leaves it out), so no role process,
//! no other host and no run directory ever holds the token.

use super::{Goal, Scenario, Validated};
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;

/// Where `scmpc run --live` serves without an address.
pub const DEFAULT_LIVE_ADDRESS: &str = "127.0.0.1:8765";
/// The shortest `live.token` accepted.
pub const MIN_TOKEN_CHARS: usize = 16;

/// `[live]`: serve the run over Foxglove's WebSocket protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct LiveConfig {
    /// `IP:PORT` to listen on (port 0: any free port, printed when the run starts).
    pub address: String,
    /// The shared secret a client gives as `?token=` in its URL or as `Authorization:
    /// Bearer`; required on any address but loopback. Empty: none.
    pub token: String,
    /// Whether a client may send the robot a goal on `/goal` (else every goal is refused);
    /// needs a token.
    pub accept_goals: bool,
    /// Lockstep: hold the clock to real time, so that the view shows the run at the pace
    /// it would drive (`false`: as fast as the run goes).
    pub pace: bool,
}

impl Default for LiveConfig {
    fn default() -> Self {
        LiveConfig {
            address: DEFAULT_LIVE_ADDRESS.into(),
            token: String::new(),
            accept_goals: false,
            pace: false,
        }
    }
}

impl LiveConfig {
    /// The address to listen on, if `address` is one.
    pub fn socket_address(&self) -> Result<SocketAddr, String> {
        self.address.parse().map_err(|_| {
            format!(
                "`{}` is not an IP address and port (e.g. `{DEFAULT_LIVE_ADDRESS}`)",
                self.address
            )
        })
    }

    /// Every problem of the section, with its key (`live.*`).
    pub fn problems(&self) -> Vec<(&'static str, String)> {
        let mut problems = Vec::new();
        match self.socket_address() {
            Err(e) => problems.push(("live.address", e)),
            Ok(address) if !address.ip().is_loopback() && self.token.is_empty() => problems.push((
                "live.token",
                format!(
                    "`live.address = \"{}\"` is not a loopback address: a client must give a \
                     token (or reach a loopback address through an SSH tunnel; \
                     docs/foxglove.md)",
                    self.address
                ),
            )),
            Ok(_) => {}
        }
        if self.accept_goals && self.token.is_empty() {
            problems.push((
                "live.token",
                "`live.accept_goals = true`: steering needs a token, even on loopback (any \
                 web page open on this machine may reach a loopback server)"
                    .into(),
            ));
        }
        if !self.token.is_empty() && self.token.chars().count() < MIN_TOKEN_CHARS {
            problems.push((
                "live.token",
                format!("a token must have at least {MIN_TOKEN_CHARS} characters"),
            ));
        }
        if !self.token.chars().all(is_unreserved) {
            problems.push((
                "live.token",
                "a token is made of letters, digits, `-`, `.`, `_` and `~` only (it is sent in \
                 a URL as it is)"
                    .into(),
            ));
        }
        problems
    }
}

impl Scenario {
    /// A goal sent while the run drives, checked as RViz's "2D Goal Pose" would be (the
    /// robot can reach it as far as anyone knows): finite, inside the position box and off
    /// every known obstacle, grown by the robot's footprint. Its heading is kept only for a
    /// robot that settles at its goal (as a ROS 2 goal's is). `Err`: why it is refused.
    pub fn live_goal(&self, goal: Goal) -> Result<Goal, String> {
        let [x, y] = goal.position;
        if !(x.is_finite() && y.is_finite() && goal.yaw_rad.is_none_or(f64::is_finite)) {
            return Err(format!("({x}, {y}) is not a finite position and heading"));
        }
        if self.outside_position_box([x, y]) {
            return Err(format!(
                "({x}, {y}) is outside {}: no plan can reach it",
                self.position_box()
            ));
        }
        let radius = crate::ObstacleGrowth::footprint(self).fixed_m;
        let known: Vec<&crate::Obstacle> = self.known_obstacles().collect();
        for (i, o) in self.obstacles.iter().enumerate() {
            let inside = o
                .rest()
                .is_some_and(|rest| crate::distance(rest, [x, y]) <= o.radius + radius);
            if inside && known.iter().any(|k| std::ptr::eq(*k, o)) {
                return Err(format!(
                    "({x}, {y}) is inside obstacle {i} (radius {} m at ({}, {})), grown by the \
                     robot's radius {radius} m",
                    o.radius, o.x, o.y
                ));
            }
        }
        let settles = self.robot.final_approach == crate::FinalApproach::Settle;
        Ok(Goal {
            yaw_rad: goal.yaw_rad.filter(|_| settles),
            ..goal
        })
    }
}

impl Validated {
    /// The same scenario going to `goal` instead, a goal [`Scenario::live_goal`] gave: what
    /// a role retargets to while the run drives.
    pub fn with_goal(&self, goal: Goal) -> Validated {
        let mut scenario = self.0.clone();
        scenario.robot.goal = goal;
        Validated(scenario)
    }
}

/// Whether `c` stands for itself in a URL (RFC 3986's unreserved characters).
fn is_unreserved(c: char) -> bool {
    c.is_ascii_alphanumeric() || "-._~".contains(c)
}
