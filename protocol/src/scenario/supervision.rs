//! `[supervision]`: what the orchestrator does when a role process dies, a host is lost,
//! or a replacement does not warm up (docs/running.md, docs/hosts.md).

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum RestartPolicy {
    Always,
    Never,
}

/// What the orchestrator does when a role process dies (a dead plant always ends the run).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Supervision {
    /// Restart a dead estimator, MPC or DFL (a dead plant always ends the run).
    pub restart: RestartPolicy,
    /// Restarts allowed over the whole run.
    pub max_restarts: u32,
    /// When the host of a role is lost (docs/hosts.md): `none` ends the run `aborted`;
    /// `local` starts a replacement on the orchestrator's host and the run goes on.
    pub failover: Failover,
    /// How long a replacement (`[[swap]]`, `scmpc swap`) has to publish outputs spanning two
    /// samples after it was started, s; one that has not is stopped, and the swap fails
    /// with the old process still running. A replacement slow to start (a Python process
    /// importing much, say) needs more.
    pub swap_timeout_s: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Failover {
    None,
    Local,
}

impl Default for Supervision {
    fn default() -> Self {
        Supervision {
            restart: RestartPolicy::Always,
            max_restarts: 3,
            failover: Failover::None,
            swap_timeout_s: 10.0,
        }
    }
}
