//! One clock across hosts (docs/hosts.md). Monotonic clocks of two machines do not agree:
//! an agent asks the orchestrator's clock for its time several times and keeps the
//! exchange with the shortest round trip, whose midpoint is when the orchestrator read its
//! clock to within half that round trip (Cristian's method). The difference is the
//! correction the host's role processes add to their clock
//! ([`runtime::clock::ENV_CLOCK_CORRECTION_NS`]), so every deadline and time stamp of the
//! run is on the orchestrator's clock; half the round trip is its uncertainty.

use crate::HostError;
use crate::keys;
use runtime::clock::monotonic_ns;
use std::time::Duration;
use zenoh::Wait;

/// Exchanges of time stamps per estimate.
pub const EXCHANGES: usize = 16;

/// What an agent knows of its link to the orchestrator.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ClockLink {
    /// What to add to this host's clock to read the orchestrator's, ns.
    pub correction_ns: i64,
    /// The shortest round trip seen, ns.
    pub round_trip_ns: u64,
}

impl ClockLink {
    /// How far the correction may be off: half the shortest round trip, ns.
    pub fn uncertainty_ns(&self) -> u64 {
        self.round_trip_ns / 2
    }
}

/// The orchestrator's side: answers every query on the run's clock key with its time.
pub fn serve(
    session: &zenoh::Session,
    run: &str,
) -> Result<zenoh::query::Queryable<()>, HostError> {
    session
        .declare_queryable(keys::clock(run))
        .callback(|query| {
            let now = monotonic_ns().to_le_bytes().to_vec();
            let _ = query.reply(query.key_expr().clone(), now).wait();
        })
        .wait()
        .map_err(|e| HostError::Zenoh(format!("serving the clock: {e}")))
}

/// The agent's side: [`EXCHANGES`] exchanges with the orchestrator's clock.
pub fn estimate(session: &zenoh::Session, run: &str) -> Result<ClockLink, HostError> {
    let mut best: Option<ClockLink> = None;
    for _ in 0..EXCHANGES {
        let sent = monotonic_ns();
        let replies = session
            .get(keys::clock(run))
            .timeout(Duration::from_secs(2))
            .wait()
            .map_err(|e| HostError::Zenoh(format!("asking the clock: {e}")))?;
        let Ok(reply) = replies.recv() else { continue };
        let received = monotonic_ns();
        let Ok(sample) = reply.result() else { continue };
        let Ok(bytes) = <[u8; 8]>::try_from(sample.payload().to_bytes().as_ref()) else {
            continue;
        };
        let theirs = u64::from_le_bytes(bytes);
        let round_trip_ns = received.saturating_sub(sent);
        let midpoint = sent + round_trip_ns / 2;
        let link = ClockLink {
            correction_ns: theirs as i64 - midpoint as i64,
            round_trip_ns,
        };
        if best.is_none_or(|b| link.round_trip_ns < b.round_trip_ns) {
            best = Some(link);
        }
    }
    best.ok_or_else(|| HostError::Zenoh("the orchestrator's clock did not answer".into()))
}
