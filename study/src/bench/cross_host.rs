//! The cross-host part of `scmpc bench` (docs/hosts.md), on loopback:
//!
//! - Baseline: a raw Zenoh ping-pong between this process and a `scmpc bench-pong --zenoh`
//!   child (one publisher and one subscriber a side, express, as the bridges use them),
//!   one ping per inner tick, each direction measured as the pipeline's hops are.
//! - Cross host: the paper run in real time with the MPC on a second host (a
//!   `scmpc host` agent started for the bench): the estimate's hop from the estimator to
//!   the MPC crosses the link (iceoryx2 to the bridge, Zenoh, the bridge to iceoryx2).

use super::{KillOnDrop, PING_PERIOD_NS, ROUNDS, WARM_UP};
use anyhow::{Context, anyhow};
use hosts::net::{self, Security};
use protocol::Validated;
use protocol::endpoint::Endpoint;
use record::Percentiles;
use run::multiproc::{self, HostsSetup};
use run::sinks::Recording;
use runtime::clock::{RunMode, monotonic_ns, sleep_until_ns};
use runtime::ipc;
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use zenoh::Wait;
use zenoh::qos::CongestionControl;

const PING_KEY: &str = "scmpc/bench/ping";
const PONG_KEY: &str = "scmpc/bench/pong";
/// The name of the bench's second host.
const HOST: &str = "bench";
/// The hop that crosses the link in the cross-host run (the estimate, to the MPC).
const CROSSING_HOP: &str = "estimate_to_mpc";

/// The cross-host figures of `bench.json`.
#[derive(Debug, Serialize)]
pub struct CrossHost {
    /// Publish-to-receipt latency of the raw Zenoh ping-pong, both directions, µs.
    pub raw_zenoh_one_way_us: Percentiles,
    /// Publish-to-receipt of the estimate from the estimator to the MPC on the other host
    /// (iceoryx2, the bridges and Zenoh), µs.
    pub cross_host_hop_us: Percentiles,
    /// `cross_host_hop_us.p50 / raw_zenoh_one_way_us.p50`.
    pub cross_host_ratio_p50: f64,
    /// The link's shortest round trip in the clock exchange, µs.
    pub link_round_trip_us: f64,
    pub cross_host_deadline_misses: u64,
}

/// Measures both on loopback; the cross-host run (`scenario`, in real time) goes to `out`.
pub fn measure(out: &Path, scenario: &Validated, stop: &AtomicBool) -> anyhow::Result<CrossHost> {
    let raw = Percentiles::of(&zenoh_ping_pong(stop)?);
    let endpoint = free_loopback_endpoint()?;
    let _agent = start_agent(&endpoint)?;
    let remote = scenario.with_overrides(&[format!("hosts.mpc={HOST}")], "the bench")?;
    let hosts = HostsSetup {
        endpoints: BTreeMap::from([(HOST.to_string(), endpoint)]),
        security: Security::default(),
    };
    let summary = multiproc::run(
        &remote,
        out,
        RunMode::Realtime,
        &ipc::new_prefix(),
        &hosts,
        Recording::files(false),
        stop,
    )?;
    run::stop::check(stop)?;
    let processes = summary
        .processes
        .as_ref()
        .ok_or_else(|| anyhow!("the cross-host run reported no processes"))?;
    let hop = *processes
        .hop_latency_by_hop_us
        .get(CROSSING_HOP)
        .ok_or_else(|| anyhow!("the cross-host run measured no {CROSSING_HOP} hop"))?;
    Ok(CrossHost {
        raw_zenoh_one_way_us: raw,
        cross_host_hop_us: hop,
        cross_host_ratio_p50: hop.p50 / raw.p50.max(1e-9),
        link_round_trip_us: processes
            .links
            .get(HOST)
            .map_or(f64::NAN, |l| l.round_trip_us),
        cross_host_deadline_misses: summary.deadline_misses,
    })
}

/// A loopback TCP endpoint on a port free a moment ago.
fn free_loopback_endpoint() -> anyhow::Result<Endpoint> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .context("finding a free port")?
        .port();
    Endpoint::parse(&format!("tcp/127.0.0.1:{port}")).map_err(|e| anyhow!(e))
}

/// `scmpc host --name bench` on `endpoint`, once it listens; interrupted (so it ends
/// cleanly) and reaped when dropped.
fn start_agent(endpoint: &Endpoint) -> anyhow::Result<Agent> {
    let mut child = std::process::Command::new(std::env::current_exe()?)
        .process_group(0)
        .args(["host", "--name", HOST, "--listen", &endpoint.zenoh()])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .context("starting scmpc host")?;
    let stderr = child.stderr.take().context("the agent's stderr")?;
    let agent = Agent(KillOnDrop(child));
    let mut lines = BufReader::new(stderr).lines();
    loop {
        match lines.next() {
            Some(Ok(line)) if line.contains("listening on") => break,
            Some(Ok(_)) => {}
            _ => return Err(anyhow!("the bench's agent ended before it listened")),
        }
    }
    // Drained, so the agent never blocks on a full pipe.
    std::thread::spawn(move || lines.for_each(drop));
    Ok(agent)
}

struct Agent(KillOnDrop);

impl Drop for Agent {
    fn drop(&mut self) {
        let child = &mut (self.0).0;
        // SAFETY: signalling the agent this process started.
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while child.try_wait().ok().flatten().is_none() && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
    }
}

/// A ping or pong: `[seq, publish_ns, ping_latency_ns]`, little-endian.
fn encode(seq: u64, publish_ns: u64, ping_latency_ns: u64) -> Vec<u8> {
    [seq, publish_ns, ping_latency_ns]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

fn decode(bytes: &[u8]) -> Option<[u64; 3]> {
    let word = |i: usize| {
        Some(u64::from_le_bytes(
            bytes.get(8 * i..8 * i + 8)?.try_into().ok()?,
        ))
    };
    Some([word(0)?, word(1)?, word(2)?])
}

fn session(listen: &[Endpoint], connect: &[Endpoint]) -> anyhow::Result<zenoh::Session> {
    Ok(net::open(net::config(
        listen,
        connect,
        &Security::default(),
    )?)?)
}

fn publisher<'a>(
    session: &'a zenoh::Session,
    key: &'static str,
) -> anyhow::Result<zenoh::pubsub::Publisher<'a>> {
    session
        .declare_publisher(key)
        .congestion_control(CongestionControl::Block)
        .express(true)
        .wait()
        .map_err(|e| anyhow!("zenoh publisher {key}: {e}"))
}

/// `scmpc bench-pong --zenoh ENDPOINT`: answers every ping with a pong carrying the
/// ping's latency, until the last ping or 10 s without one.
pub fn zenoh_pong(endpoint: &Endpoint) -> anyhow::Result<()> {
    let session = session(&[], std::slice::from_ref(endpoint))?;
    let pongs = publisher(&session, PONG_KEY)?;
    let pings = session
        .declare_subscriber(PING_KEY)
        .wait()
        .map_err(|e| anyhow!("zenoh subscriber: {e}"))?;
    while let Ok(Some(sample)) = pings.recv_timeout(Duration::from_secs(10)) {
        let received_ns = monotonic_ns();
        let Some([seq, publish_ns, _]) = decode(&sample.payload().to_bytes()) else {
            continue;
        };
        if seq == u64::MAX {
            break;
        }
        let pong = encode(seq, monotonic_ns(), received_ns.saturating_sub(publish_ns));
        pongs
            .put(pong)
            .wait()
            .map_err(|e| anyhow!("zenoh put: {e}"))?;
    }
    Ok(())
}

/// Publish-to-receipt latencies of the raw Zenoh ping-pong, both directions, µs.
fn zenoh_ping_pong(stop: &AtomicBool) -> anyhow::Result<Vec<f64>> {
    let endpoint = free_loopback_endpoint()?;
    let session = session(std::slice::from_ref(&endpoint), &[])?;
    let pings = publisher(&session, PING_KEY)?;
    let pongs = session
        .declare_subscriber(PONG_KEY)
        .wait()
        .map_err(|e| anyhow!("zenoh subscriber: {e}"))?;
    let child = std::process::Command::new(std::env::current_exe()?)
        .process_group(0)
        .args(["bench-pong", "--zenoh", &endpoint.zenoh()])
        .stdout(std::process::Stdio::null())
        .spawn()
        .context("starting scmpc bench-pong --zenoh")?;
    let mut child = KillOnDrop(child);
    let ping = |seq: u64| {
        pings
            .put(encode(seq, monotonic_ns(), 0))
            .wait()
            .map_err(|e| anyhow!("zenoh put: {e}"))
    };
    // Until the other side answers.
    let deadline = monotonic_ns() + 10_000_000_000;
    loop {
        ping(0)?;
        if let Ok(Some(_)) = pongs.recv_timeout(Duration::from_millis(20)) {
            break;
        }
        if monotonic_ns() > deadline {
            return Err(anyhow!("no Zenoh pong within 10 s"));
        }
    }
    while let Ok(Some(_)) = pongs.try_recv() {}
    let mut one_way = Vec::with_capacity(2 * ROUNDS as usize);
    let mut next = monotonic_ns();
    for seq in 1..=ROUNDS + WARM_UP {
        run::stop::check(stop)?;
        next += PING_PERIOD_NS;
        sleep_until_ns(next);
        ping(seq)?;
        let answered = loop {
            let sample = pongs
                .recv_timeout(Duration::from_secs(1))
                .ok()
                .flatten()
                .ok_or_else(|| anyhow!("no Zenoh pong for ping {seq} within 1 s"))?;
            let received_ns = monotonic_ns();
            if let Some([s, publish_ns, ping_latency_ns]) = decode(&sample.payload().to_bytes())
                && s == seq
            {
                break [ping_latency_ns, received_ns.saturating_sub(publish_ns)];
            }
        };
        if seq > WARM_UP {
            one_way.extend(answered.map(|ns| ns as f64 / 1e3));
        }
    }
    ping(u64::MAX)?;
    let _ = child.0.wait();
    Ok(one_way)
}
