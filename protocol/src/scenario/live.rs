//! `[live]`: the run served to Foxglove while it drives (docs/foxglove.md, "Live").
//!
//! How a run is watched is not part of the experiment: the section is never written out
//! ([`Scenario::to_toml`](crate::Scenario::to_toml) leaves it out), so no role process,
//! no other host and no run directory ever holds the token.

use serde::{Deserialize, Serialize};
use std::net::SocketAddr;

/// Where `scmpc run --live` serves without an address.
pub const DEFAULT_LIVE_ADDRESS: &str = "127.0.0.1:8765";
/// The shortest `live.token` accepted.
pub const MIN_TOKEN_CHARS: usize = 16;

/// `[live]`: serve the run over Foxglove's WebSocket protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LiveConfig {
    /// `IP:PORT` to listen on (port 0: any free port, printed when the run starts).
    pub address: String,
    /// The shared secret a client gives as `?token=` in its URL or as `Authorization:
    /// Bearer`; required on any address but loopback. Empty: none.
    pub token: String,
    /// Lockstep: hold the clock to real time, so that the view shows the run at the pace
    /// it would drive (`false`: as fast as the run goes).
    pub pace: bool,
}

impl Default for LiveConfig {
    fn default() -> Self {
        LiveConfig {
            address: DEFAULT_LIVE_ADDRESS.into(),
            token: String::new(),
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

/// Whether `c` stands for itself in a URL (RFC 3986's unreserved characters).
fn is_unreserved(c: char) -> bool {
    c.is_ascii_alphanumeric() || "-._~".contains(c)
}
