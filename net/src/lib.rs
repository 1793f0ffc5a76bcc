//! The Zenoh network of a run: peers that connect only where they are told (no multicast
//! scouting, no gossip), over TCP on loopback, or over TLS with mutual authentication
//! anywhere else. A non-loopback endpoint without TLS is refused unless the user says
//! `--insecure`. The hosts' bridges and agents and the ROS 2 robot's link share it; it
//! knows neither iceoryx2 nor the roles.

use protocol::endpoint::{Endpoint, Transport};
use std::path::PathBuf;
use zenoh::Wait;

/// What can go wrong setting up or opening a Zenoh session.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// Nothing answers at the endpoint (Zenoh's words follow).
    #[error("nothing answers at the endpoint ({0})")]
    Unreachable(String),
}

/// The files of TLS with mutual authentication: the CA both sides trust, and this side's
/// certificate and private key (PEM).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    pub ca: PathBuf,
    pub certificate: PathBuf,
    pub private_key: PathBuf,
}

/// How this side secures its Zenoh links.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Security {
    pub tls: Option<TlsFiles>,
    /// Plain TCP off loopback, on the user's explicit word.
    pub insecure: bool,
}

impl Security {
    /// Whether `endpoint` may be used: loopback, TLS configured (a `tls/` endpoint needs
    /// it), or `--insecure`. The error names what to give.
    pub fn allows(&self, endpoint: &Endpoint) -> Result<(), String> {
        match (endpoint.transport, &self.tls) {
            (Transport::Tls, None) => Err(format!(
                "{} is a TLS endpoint: give --tls-ca, --tls-cert and --tls-key",
                endpoint.zenoh()
            )),
            (Transport::Tcp, Some(_)) => Err(format!(
                "{} is plain TCP while TLS is configured: use tls/{}:{}",
                endpoint.zenoh(),
                endpoint.address,
                endpoint.port
            )),
            (Transport::Tcp, None) if !endpoint.is_loopback() && !self.insecure => Err(format!(
                "{} is not on loopback: configure TLS with mutual authentication \
                 (--tls-ca, --tls-cert, --tls-key) or give --insecure",
                endpoint.zenoh()
            )),
            _ => Ok(()),
        }
    }

    /// Checks that the TLS files can be read.
    pub fn check_files(&self) -> Result<(), String> {
        let Some(tls) = &self.tls else {
            return Ok(());
        };
        for (option, path) in [
            ("--tls-ca", &tls.ca),
            ("--tls-cert", &tls.certificate),
            ("--tls-key", &tls.private_key),
        ] {
            std::fs::metadata(path).map_err(|e| format!("{option} {}: {e}", path.display()))?;
        }
        Ok(())
    }
}

/// The configuration of a peer that listens on `listen` and connects to `connect`.
pub fn config(
    listen: &[Endpoint],
    connect: &[Endpoint],
    security: &Security,
) -> Result<zenoh::Config, NetError> {
    let mut config = zenoh::Config::default();
    let mut set = |key: &str, value: serde_json::Value| {
        config
            .insert_json5(key, &value.to_string())
            .map_err(|e| NetError::Zenoh(format!("config {key}: {e}")))
    };
    let zenoh_endpoints = |list: &[Endpoint]| {
        serde_json::Value::from(list.iter().map(Endpoint::zenoh).collect::<Vec<_>>())
    };
    set("mode", "peer".into())?;
    set("listen/endpoints", zenoh_endpoints(listen))?;
    set("connect/endpoints", zenoh_endpoints(connect))?;
    set("scouting/multicast/enabled", false.into())?;
    set("scouting/gossip/enabled", false.into())?;
    if let Some(tls) = &security.tls {
        // Each host both listens and connects with the same certificate and key.
        for (key, path) in [
            ("root_ca_certificate", &tls.ca),
            ("listen_certificate", &tls.certificate),
            ("listen_private_key", &tls.private_key),
            ("connect_certificate", &tls.certificate),
            ("connect_private_key", &tls.private_key),
        ] {
            let path = serde_json::Value::from(path.display().to_string());
            set(&format!("transport/link/tls/{key}"), path)?;
        }
        set("transport/link/tls/enable_mtls", true.into())?;
        set("transport/link/tls/verify_name_on_connect", false.into())?;
    }
    Ok(config)
}

/// The configuration of a client of the Zenoh router at `router` (a ROS 2 robot's
/// `rmw_zenohd`, docs/ros2.md): it connects there alone and fails at once when it cannot.
pub fn client_config(router: &Endpoint, security: &Security) -> Result<zenoh::Config, NetError> {
    let mut config = config(&[], std::slice::from_ref(router), security)?;
    config
        .insert_json5("mode", "\"client\"")
        .map_err(|e| NetError::Zenoh(format!("config mode: {e}")))?;
    Ok(config)
}

/// The environment that hands a role process this side's TLS files (the robot process
/// of `plant.kind = "ros2"` connects to the robot's router with them).
pub const ENV_TLS: [&str; 3] = ["SCMPC_TLS_CA", "SCMPC_TLS_CERT", "SCMPC_TLS_KEY"];

impl Security {
    /// The TLS files as [`ENV_TLS`] variables (none without TLS).
    pub fn to_env(&self) -> Vec<(String, String)> {
        let Some(tls) = &self.tls else {
            return Vec::new();
        };
        ENV_TLS
            .iter()
            .zip([&tls.ca, &tls.certificate, &tls.private_key])
            .map(|(name, path)| (name.to_string(), path.display().to_string()))
            .collect()
    }

    /// The TLS files of [`ENV_TLS`], when all three are set.
    pub fn from_env() -> Security {
        let [ca, certificate, private_key] = ENV_TLS.map(std::env::var_os);
        let tls = match (ca, certificate, private_key) {
            (Some(ca), Some(certificate), Some(private_key)) => Some(TlsFiles {
                ca: ca.into(),
                certificate: certificate.into(),
                private_key: private_key.into(),
            }),
            _ => None,
        };
        Security {
            tls,
            insecure: false,
        }
    }
}

/// Opens a session with `config`.
pub fn open(config: zenoh::Config) -> Result<zenoh::Session, NetError> {
    zenoh::open(config).wait().map_err(|e| {
        let said = without_location(&e.to_string());
        if said.starts_with("Unable to connect") {
            NetError::Unreachable(said)
        } else {
            NetError::Zenoh(format!("opening a session: {said}"))
        }
    })
}

/// A Zenoh error's text without the source file it was raised in (` at /…/file.rs:447.`):
/// a path of the machine that built the executable says nothing to its user.
fn without_location(text: &str) -> String {
    match text.rfind(" at /") {
        Some(at) if text[at..].contains(".rs:") => text[..at].trim_end().to_string(),
        _ => text.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_zenoh_error_loses_the_source_path_of_the_build_machine() {
        let said = "Unable to connect to any of [Single(tcp/127.0.0.1:7447)]! at \
                    /root/.cargo/registry/src/x/zenoh-1.10.2/src/net/runtime/orchestrator.rs:447.";
        assert_eq!(
            without_location(said),
            "Unable to connect to any of [Single(tcp/127.0.0.1:7447)]!"
        );
        assert_eq!(without_location("no path here"), "no path here");
    }

    #[test]
    fn plain_tcp_off_loopback_needs_tls_or_insecure() {
        let remote = Endpoint::parse("tcp/10.0.0.7:7447").unwrap();
        let local = Endpoint::parse("tcp/127.0.0.1:7447").unwrap();
        let plain = Security::default();
        assert!(plain.allows(&local).is_ok());
        let refused = plain.allows(&remote).unwrap_err();
        assert!(
            refused.contains("--insecure") && refused.contains("--tls-ca"),
            "{refused}"
        );
        let insecure = Security {
            insecure: true,
            ..Security::default()
        };
        assert!(insecure.allows(&remote).is_ok());
        let tls_endpoint = Endpoint::parse("tls/10.0.0.7:7447").unwrap();
        assert!(
            plain
                .allows(&tls_endpoint)
                .unwrap_err()
                .contains("--tls-cert")
        );
        let tls = Security {
            tls: Some(TlsFiles {
                ca: "ca.pem".into(),
                certificate: "cert.pem".into(),
                private_key: "key.pem".into(),
            }),
            insecure: false,
        };
        assert!(tls.allows(&tls_endpoint).is_ok());
        assert!(tls.allows(&remote).is_err(), "TLS configured: no plain TCP");
        assert!(config(std::slice::from_ref(&local), &[], &tls).is_ok());
    }
}
