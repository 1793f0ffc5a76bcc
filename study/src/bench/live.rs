//! The live view's cost in `scmpc bench` (docs/foxglove.md, "Live"): the paper run in real
//! time again, served with `--live` to one client that subscribes to every channel and reads
//! everything, against the same run without a live view.

use crate::foxglove_client::{Client, Frame};
use anyhow::{Context, anyhow};
use protocol::Validated;
use record::{Percentiles, Summary};
use run::multiproc;
use run::sinks::Recording;
use runtime::clock::RunMode;
use runtime::ipc;
use serde::Serialize;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

/// How long the client tries to connect while the run starts.
const CONNECT_WITHIN: Duration = Duration::from_secs(10);

/// The live figures of `bench.json`.
#[derive(Debug, Serialize)]
pub struct LiveCost {
    /// Publish-to-receipt of every hop of the pipeline with a live client reading, µs.
    pub live_hop_us: Percentiles,
    /// `live_hop_us.p99` over the hop p99 of the same run without a live view.
    pub live_hop_ratio_p99: f64,
    /// Messages the client received.
    pub live_messages: u64,
    pub live_deadline_misses: u64,
}

/// Runs `scenario` in real time with a live view and a client into `out`; `without` is the
/// same run without one.
pub fn measure(
    out: &Path,
    scenario: &Validated,
    without: &Summary,
    stop: &AtomicBool,
) -> anyhow::Result<LiveCost> {
    let hops = |run: &Summary| {
        (run.processes.as_ref())
            .map(|p| p.hop_latency_us)
            .ok_or_else(|| anyhow!("a real-time run reported no processes"))
    };
    let without = hops(without)?;
    let address = free_loopback_address()?;
    let served = scenario.with_overrides(&[format!("live.address={address}")], "the bench")?;
    let url = format!("ws://{address}");
    let client = std::thread::spawn(move || read_everything(&url));
    let run = multiproc::run(
        &served,
        out,
        RunMode::Realtime,
        &ipc::new_prefix(),
        &multiproc::HostsSetup::default(),
        Recording {
            live: true,
            ..Recording::files(false)
        },
        stop,
    )?;
    let live_messages = (client.join())
        .map_err(|_| anyhow!("the live client panicked"))?
        .context("the live client")?;
    let live_hop_us = hops(&run)?;
    Ok(LiveCost {
        live_hop_us,
        live_hop_ratio_p99: live_hop_us.p99 / without.p99.max(1e-9),
        live_messages,
        live_deadline_misses: run.deadline_misses,
    })
}

/// A loopback address no one listens on now.
fn free_loopback_address() -> anyhow::Result<std::net::SocketAddr> {
    let listener = std::net::TcpListener::bind("127.0.0.1:0")?;
    Ok(listener.local_addr()?)
}

/// Connects as soon as the server listens, subscribes to every channel and reads until the
/// server closes: the messages received.
fn read_everything(url: &str) -> anyhow::Result<u64> {
    let started = Instant::now();
    let mut client = loop {
        match Client::connect(url, true) {
            Ok(client) => break client,
            Err(_) if started.elapsed() < CONNECT_WITHIN => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => return Err(e).context(format!("connecting to {url}")),
        }
    };
    let mut messages = 0;
    while let Ok(frame) = client.read() {
        if let Frame::Data { .. } = frame {
            messages += 1;
        }
    }
    Ok(messages)
}
