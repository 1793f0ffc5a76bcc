//! `[hosts]`: where the roles run (docs/hosts.md).

use serde::{Deserialize, Serialize};

/// Where the roles run (docs/hosts.md): the name of a host per role, empty for the
/// orchestrator's host (the plant, the simulated robot, always runs there), and where each
/// named host's agent listens.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct HostsConfig {
    /// The host the estimator runs on (empty: the orchestrator's).
    pub estimator: String,
    /// The host the MPC runs on (empty: the orchestrator's).
    pub mpc: String,
    /// The host the DFL runs on (empty: the orchestrator's).
    pub dfl: String,
    /// The host the route planner runs on (empty: the orchestrator's).
    pub planner: String,
    /// The host the tracker runs on (empty: the orchestrator's).
    pub tracker: String,
    /// Host name to the Zenoh endpoint its agent listens on (`tcp/ADDR:PORT` or
    /// `tls/ADDR:PORT`); `scmpc run --host NAME=ENDPOINT` adds to it.
    pub endpoints: std::collections::BTreeMap<String, String>,
    /// How long the orchestrator asks each host's agent to join the run before the run
    /// fails, naming the host, s. A host behind a slow link may need more.
    pub join_timeout_s: f64,
}

impl Default for HostsConfig {
    fn default() -> Self {
        HostsConfig {
            estimator: String::new(),
            mpc: String::new(),
            dfl: String::new(),
            planner: String::new(),
            tracker: String::new(),
            endpoints: std::collections::BTreeMap::new(),
            join_timeout_s: 5.0,
        }
    }
}

impl HostsConfig {
    /// `join_timeout_s` ([`crate::wait_of_s`]).
    pub fn join_timeout(&self) -> std::time::Duration {
        crate::wait_of_s(self.join_timeout_s)
    }

    /// The host `role` runs on (`None`: the orchestrator's).
    pub fn of(&self, role: crate::Role) -> Option<&str> {
        let name = match role {
            crate::Role::Estimator => &self.estimator,
            crate::Role::Mpc => &self.mpc,
            crate::Role::Dfl => &self.dfl,
            crate::Role::Planner => &self.planner,
            crate::Role::Tracker => &self.tracker,
            // The plant, the simulated robot, always runs here; so does a role that may
            // not run elsewhere (`RoleDecl::remote`).
            _ => "",
        };
        (!name.is_empty()).then_some(name)
    }

    /// The host of `role`, to set (`None`: a role that runs on the orchestrator's host).
    pub(crate) fn role_mut(&mut self, role: crate::Role) -> Option<&mut String> {
        match role {
            crate::Role::Estimator => Some(&mut self.estimator),
            crate::Role::Mpc => Some(&mut self.mpc),
            crate::Role::Dfl => Some(&mut self.dfl),
            crate::Role::Planner => Some(&mut self.planner),
            crate::Role::Tracker => Some(&mut self.tracker),
            _ => None,
        }
    }

    /// The names of the hosts roles are placed on, each once, in order.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = crate::Role::ALL
            .iter()
            .filter_map(|r| self.of(*r).map(str::to_string))
            .collect();
        names.sort();
        names.dedup();
        names
    }
}

/// Whether `host`, at `key`, names another host (letters, digits, `-`, `_`, and not the
/// orchestrator's); if not, an error for `key`.
pub(super) fn check_host_name(v: &mut super::validate::Validator, key: &str, host: &str) -> bool {
    let orchestrator = crate::endpoint::ORCHESTRATOR_HOST;
    let named = crate::endpoint::is_host_name(host) && host != orchestrator;
    if !named {
        v.fail(
            key,
            format!("`{host}` is no host name (letters, digits, `-`, `_`, not `{orchestrator}`)"),
        );
    }
    named
}

impl super::Scenario {
    /// Host names name hosts, endpoints parse, and a host's endpoint is known when it is
    /// given in the scenario.
    pub(super) fn check_hosts(&self, v: &mut super::validate::Validator) {
        v.positive("hosts.join_timeout_s", self.hosts.join_timeout_s);
        for role in crate::Role::ALL {
            let Some(host) = self.hosts.of(role) else {
                continue;
            };
            let key = format!("hosts.{}", role.as_str());
            if !check_host_name(v, &key, host) {
                continue;
            }
            if !crate::graph::declaration(role, self.plant.kind).remote {
                v.fail(
                    &key,
                    "this role runs on the orchestrator's host only".into(),
                );
            }
        }
        for (name, endpoint) in &self.hosts.endpoints {
            let key = format!("hosts.endpoints.{name}");
            if !check_host_name(v, &key, name) {
                continue;
            }
            if let Err(e) = crate::endpoint::Endpoint::parse(endpoint) {
                v.fail(&key, e);
            }
        }
        for role in [crate::Role::Planner, crate::Role::Tracker] {
            if self.hosts.of(role).is_some()
                && let Some(why) = self.absent(role)
            {
                v.fail(&format!("hosts.{}", role.as_str()), why);
            }
        }
    }
}
