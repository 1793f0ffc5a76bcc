//! The Zenoh side of a run whose roles run on several hosts (docs/hosts.md): the bridge
//! of each host between its iceoryx2 topics and Zenoh ([`bridge`]), the clock across hosts
//! ([`clock_sync`]), the key of the run that authenticates every bridged sample
//! ([`auth`]), the network's security ([`net`]), its keys ([`keys`]) and what the
//! orchestrator and an agent tell each other ([`messages`]). Role processes know none of
//! it: on every host they see local iceoryx2 topics only.

pub mod auth;
pub mod bridge;
pub mod clock_sync;
pub mod keys;
pub mod messages;
pub mod net;
pub mod routes;

/// What can go wrong on the Zenoh side.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error(transparent)]
    Ipc(#[from] runtime::ipc::IpcError),
    #[error("bridge: {0}")]
    Bridge(String),
    #[error("{0}")]
    Protocol(String),
}

/// What a bridge has carried and refused.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct LinkCounters {
    /// Samples sent on the link.
    pub sent: u64,
    /// Samples received and published on this host.
    pub received: u64,
    /// Data samples dropped by `fault.link_loss`.
    pub lost: u64,
    /// Data samples dropped while `fault.link_down_s` cut the link.
    pub down: u64,
    /// Samples received whose tag did not verify (not from a bridge of the run).
    pub refused_tag: u64,
    /// Samples not sent: not from the publisher their producer is pinned to.
    pub refused_origin: u64,
}

impl std::ops::Add for LinkCounters {
    type Output = LinkCounters;
    fn add(self, o: LinkCounters) -> LinkCounters {
        LinkCounters {
            sent: self.sent + o.sent,
            received: self.received + o.received,
            lost: self.lost + o.lost,
            down: self.down + o.down,
            refused_tag: self.refused_tag + o.refused_tag,
            refused_origin: self.refused_origin + o.refused_origin,
        }
    }
}
