//! The Zenoh side of a run whose roles run on several hosts (docs/hosts.md): the bridge
//! of each host between its iceoryx2 topics and Zenoh ([`bridge`]), the clock across hosts
//! ([`clock_sync`]), the key of the run that authenticates every bridged sample
//! ([`auth`]), the network's security (crate `net`, re-exported), its keys ([`keys`]) and what the
//! orchestrator and an agent tell each other ([`messages`]). Role processes know none of
//! it: on every host they see local iceoryx2 topics only.

pub mod auth;
pub mod bridge;
pub mod clock_sync;
pub mod keys;
pub mod messages;
pub use ::net;
pub mod routes;

/// What can go wrong on the Zenoh side.
#[derive(Debug, thiserror::Error)]
pub enum HostError {
    #[error("zenoh: {0}")]
    Zenoh(String),
    #[error(transparent)]
    Net(#[from] net::NetError),
    #[error(transparent)]
    Ipc(#[from] runtime::ipc::IpcError),
    #[error("bridge: {0}")]
    Bridge(String),
    #[error("{0}")]
    Protocol(String),
}

/// What a bridge has carried and refused (in `protocol`, so that the record reads it
/// without linking the hosts' transports).
pub use protocol::endpoint::LinkCounters;
