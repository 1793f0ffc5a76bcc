//! `scmpc bench`: the pipeline end to end against iceoryx2's own speed.
//!
//! - Baseline: a raw iceoryx2 ping-pong between this process and a `scmpc bench-pong`
//!   child (publish-subscribe plus an event, a WaitSet on each side, the same as every
//!   hop of the pipeline, without this project's code), one ping per inner tick (5 ms,
//!   like the pipeline's samples, so both wake from idle alike). Each direction is
//!   measured as the pipeline's hops are: the receiver's clock at receipt minus the
//!   publish time stamped in the message (one monotonic clock for every process), and
//!   both directions are pooled. (Half the round trip would average two hops and hide
//!   half of each tail.)
//! - Real time: the paper run in real time: per-hop and sensor-to-actuator latency,
//!   deadline misses, each process's peak resident memory, and its MPC step against the
//!   same samples stepped in process (back to back, caches hot).
//! - Lockstep: the paper run in lockstep, with `run.mcap` and without, alternating
//!   ([`LOCKSTEP_PAIRS`] pairs): how much faster than real time, and what the recording
//!   costs.
//! - Across hosts ([`cross_host`]): a raw Zenoh ping-pong, and the real-time run with the
//!   MPC on a second host over loopback.
//! - Scaling ([`scaling`]): the MPC step against the horizon and the obstacle count.

pub mod cross_host;
pub mod fleet;
pub mod live;
pub mod load;
pub mod scaling;
pub mod targets;

use anyhow::{Context, anyhow};
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as IpcService;
use protocol::Validated;
use record::{Percentiles, Summary};
use run::multiproc;
use run::sinks::Recording;
use runtime::clock::RunMode;
use runtime::clock::{monotonic_ns, sleep_until_ns};
use runtime::ipc;
use serde::Serialize;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

/// Ping-pong payload.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
#[type_name("scmpc::BenchPing")]
pub struct Ping {
    pub seq: u64,
    /// When this message was published (monotonic clock), ns.
    pub publish_ns: u64,
    /// In a pong: the publish-to-receipt latency of the ping it answers, ns.
    pub ping_latency_ns: u64,
}

const PING: &str = "bench_ping";
const PONG: &str = "bench_pong";
/// Round trips of the baseline, and the warm-up ones not counted.
const ROUNDS: u64 = 1000;
const WARM_UP: u64 = 50;
/// Time between two pings, ns (the paper's inner tick).
const PING_PERIOD_NS: u64 = 5_000_000;

/// `bench.json`.
#[derive(Debug, Serialize)]
pub struct BenchReport {
    pub machine: String,
    /// Publish-to-receipt latency of the raw iceoryx2 ping-pong, both directions, µs.
    pub raw_iceoryx2_one_way_us: Percentiles,
    /// Publish-to-receipt of every hop of the real-time pipeline, pooled, µs.
    pub pipeline_hop_us: Percentiles,
    /// `pipeline_hop_us.p50 / raw_iceoryx2_one_way_us.p50`.
    pub hop_ratio_p50: f64,
    /// Measurement published to actuation published, ticks without a solve, µs.
    pub sensor_to_actuator_us: Percentiles,
    /// MPC step of the real-time run (update, every solve), µs.
    pub solve_us: Percentiles,
    /// MPC step of the same scenario in process (every sample stepped back to back), µs.
    pub in_process_solve_us: Percentiles,
    /// `solve_us.p50 / in_process_solve_us.p50`: what sleeping between samples costs.
    pub realtime_step_ratio_p50: f64,
    pub realtime_deadline_misses: u64,
    /// Peak resident memory of each process of the real-time run, KiB: with the real-time
    /// policy, its memory locked (the whole executable resident).
    pub peak_rss_kib: std::collections::BTreeMap<String, u64>,
    /// The same in a lockstep run, whose memory is never locked: what the processes use.
    pub peak_rss_unlocked_kib: std::collections::BTreeMap<String, u64>,
    /// Simulated time of the lockstep paper run, and its wall time with `run.mcap`
    /// (median of [`LOCKSTEP_PAIRS`] runs), s.
    pub lockstep_simulated_s: f64,
    pub lockstep_wall_s: f64,
    /// The same without `run.mcap`, s.
    pub lockstep_wall_without_mcap_s: f64,
    /// Simulated seconds per wall second in lockstep, with `run.mcap`.
    pub lockstep_speedup: f64,
    /// What `run.mcap` adds to the lockstep wall time, as a share of the run without it:
    /// the median over the pairs of `with / without - 1`.
    pub lockstep_recording_share: f64,
    /// The raw ping-pong and the real-time run again, with every core kept awake
    /// ([`run::awake`], `scmpc run --keep-cores-awake`).
    pub awake: AwakeReport,
    /// One route search ([`planner::TangentGraph::shortest_path`]) over each of
    /// [`PLANNING_FIELDS`] random fields ([`planning_field`]), by number of discs, µs.
    pub route_planning_us: std::collections::BTreeMap<usize, Percentiles>,
    #[serde(flatten)]
    pub cross_host: cross_host::CrossHost,
    /// The MPC step for every horizon and obstacle count of [`scaling`].
    pub scaling: Vec<scaling::ScalingPoint>,
    /// Its p50's growth from `N` = 8 to 30 by obstacle count ([`scaling::growth`]).
    pub scaling_growth_p50: std::collections::BTreeMap<usize, f64>,
    /// The MPC step of the built-in `field` at `N` = 30, µs ([`scaling::field_n30`]).
    pub field_n30_step_us: Percentiles,
    /// The MPC step with five moving obstacles and with the five frozen.
    pub moving_obstacles: scaling::MovingCost,
    /// The MPC step with seven robots' plans and with seven discs at rest, and `swap8`.
    pub fleet: fleet::FleetCost,
    /// The real-time run served live to a client ([`live`]).
    #[serde(flatten)]
    pub live: live::LiveCost,
    /// The targets of docs/performance.md against the numbers above ([`targets::judge`]).
    pub targets: Vec<targets::Target>,
}

/// The real-time numbers of [`BenchReport`] with every core kept awake.
#[derive(Debug, Serialize)]
pub struct AwakeReport {
    pub raw_iceoryx2_one_way_us: Percentiles,
    pub pipeline_hop_us: Percentiles,
    /// `pipeline_hop_us.p50 / raw_iceoryx2_one_way_us.p50`.
    pub hop_ratio_p50: f64,
    pub sensor_to_actuator_us: Percentiles,
    pub solve_us: Percentiles,
    /// `solve_us.p50` over the in-process step's ([`BenchReport::in_process_solve_us`]).
    pub realtime_step_ratio_p50: f64,
    pub realtime_deadline_misses: u64,
}

/// Lockstep paper runs with and without `run.mcap`, alternating: this machine's speed
/// moves from minute to minute, so the recording's cost is a median of pairs. Half the
/// pairs run the recorded run first and half the other: which run of a pair came first
/// moved the median share by 9 points on the development machine (docs/performance.md).
pub const LOCKSTEP_PAIRS: usize = 4;

/// Random fields per size in the route-planning benchmark.
pub const PLANNING_FIELDS: u64 = 1000;

/// A random field of `n` discs for the route-planning benchmarks: radii 0.2-0.8 m, centres
/// uniform in `[0.5, 7.5]^2` between a start at (8, 8) and the goal at the origin (a disc
/// over either is drawn again); seeded by `seed`.
pub fn planning_field(seed: u64, n: usize) -> Vec<planner::Disc> {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut discs = Vec::with_capacity(n);
    while discs.len() < n {
        let center = [rng.random_range(0.5..7.5), rng.random_range(0.5..7.5)];
        let radius = rng.random_range(0.2..0.8);
        let clear = |p: [f64; 2]| (center[0] - p[0]).hypot(center[1] - p[1]) > radius;
        if clear(PLANNING_START) && clear([0.0, 0.0]) {
            discs.push(planner::Disc::still(center, radius));
        }
    }
    discs
}

/// Where the route-planning benchmark's robot starts, m.
pub const PLANNING_START: [f64; 2] = [8.0, 8.0];

/// One route search over each of `fields` fields of `n` discs, µs (a field without a
/// route counts too: the search that says so is as long).
pub fn route_planning_us(n: usize, fields: u64) -> Percentiles {
    let mut graph = planner::TangentGraph::with_capacity(n);
    let bounds = [[-10.0, 10.0], [-10.0, 10.0]];
    let times: Vec<f64> = (0..fields)
        .map(|seed| {
            let discs = planning_field(seed, n);
            let started = std::time::Instant::now();
            let found = graph
                .shortest_path(PLANNING_START, [0.0, 0.0], &discs, bounds)
                .is_ok();
            std::hint::black_box(found);
            started.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    Percentiles::of(&times)
}

struct Ports<T: iceoryx2::prelude::ZeroCopySend + std::fmt::Debug + 'static> {
    publisher: iceoryx2::port::publisher::Publisher<IpcService, T, ()>,
    notifier: iceoryx2::port::notifier::Notifier<IpcService>,
}

/// The publisher and notifier of service `name`, and its subscriber and listener.
#[allow(clippy::type_complexity)]
fn open(
    node: &Node<IpcService>,
    publish_to: &str,
    listen_to: &str,
) -> anyhow::Result<(
    Ports<Ping>,
    iceoryx2::port::subscriber::Subscriber<IpcService, Ping, ()>,
    iceoryx2::port::listener::Listener<IpcService>,
)> {
    let service = |name: &str| -> anyhow::Result<_> {
        let name: ServiceName = name.try_into().map_err(|e| anyhow!("{e:?}"))?;
        let pubsub = node
            .service_builder(&name)
            .publish_subscribe::<Ping>()
            .open_or_create()
            .map_err(|e| anyhow!("{e:?}"))?;
        let event = node
            .service_builder(&name)
            .event()
            .open_or_create()
            .map_err(|e| anyhow!("{e:?}"))?;
        Ok((pubsub, event))
    };
    let (out_pubsub, out_event) = service(publish_to)?;
    let (in_pubsub, in_event) = service(listen_to)?;
    Ok((
        Ports {
            publisher: out_pubsub
                .publisher_builder()
                .create()
                .map_err(|e| anyhow!("{e:?}"))?,
            notifier: out_event
                .notifier_builder()
                .create()
                .map_err(|e| anyhow!("{e:?}"))?,
        },
        in_pubsub
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow!("{e:?}"))?,
        in_event
            .listener_builder()
            .create()
            .map_err(|e| anyhow!("{e:?}"))?,
    ))
}

fn send(ports: &Ports<Ping>, seq: u64, ping_latency_ns: u64) -> anyhow::Result<()> {
    ports
        .publisher
        .send_copy(Ping {
            seq,
            publish_ns: monotonic_ns(),
            ping_latency_ns,
        })
        .map_err(|e| anyhow!("{e:?}"))?;
    ports.notifier.notify().map_err(|e| anyhow!("{e:?}"))?;
    Ok(())
}

/// Before blocking: consumes the listener's wake-ups, then whether no sample came in
/// meanwhile (one that came between the last receive and the clearing would otherwise
/// wait unseen, its wake-up gone).
fn cleared_and_still_empty(
    listener: &iceoryx2::port::listener::Listener<IpcService>,
    subscriber: &iceoryx2::port::subscriber::Subscriber<IpcService, Ping, ()>,
) -> bool {
    let _ = listener.try_wait(|_| {});
    subscriber.has_samples().ok() == Some(false)
}

/// `scmpc bench-pong`: answers every ping until `u64::MAX` or 10 s without one.
pub fn pong(prefix: &str) -> anyhow::Result<()> {
    let node = ipc::create_node(prefix, "bench-pong", true)?;
    let (ports, subscriber, listener) = open(&node, PONG, PING)?;
    let waitset = ipc::waitset(true)?;
    let _guard = waitset
        .attach_notification(&listener)
        .map_err(|e| anyhow!("{e:?}"))?;
    loop {
        while let Some(sample) = subscriber.receive().map_err(|e| anyhow!("{e:?}"))? {
            let latency = monotonic_ns().saturating_sub(sample.payload().publish_ns);
            let seq = sample.payload().seq;
            if seq == u64::MAX {
                return Ok(());
            }
            send(&ports, seq, latency)?;
        }
        if !cleared_and_still_empty(&listener, &subscriber) {
            continue;
        }
        if ipc::wait(&waitset, Duration::from_secs(10))? != ipc::Wake::Input {
            return Ok(());
        }
    }
}

/// Publish-to-receipt latencies of the raw ping-pong, both directions, µs.
fn ping_pong(prefix: &str, stop: &AtomicBool) -> anyhow::Result<Vec<f64>> {
    let node = ipc::create_node(prefix, "bench-ping", false)?;
    let (ports, subscriber, listener) = open(&node, PING, PONG)?;
    let child = std::process::Command::new(std::env::current_exe()?)
        .process_group(0)
        .args(["bench-pong", "--prefix", prefix])
        .spawn()
        .context("starting scmpc bench-pong")?;
    // Killed and reaped however this function returns.
    let mut child = KillOnDrop(child);
    let waitset = ipc::waitset(false)?;
    let _guard = waitset
        .attach_notification(&listener)
        .map_err(|e| anyhow!("{e:?}"))?;
    // Wait until the other side has subscribed.
    let deadline = monotonic_ns() + 10_000_000_000;
    while subscriber.has_samples().ok() == Some(false) && monotonic_ns() < deadline {
        send(&ports, 0, 0)?;
        std::thread::sleep(Duration::from_millis(20));
    }
    while subscriber.receive().ok().flatten().is_some() {}
    let mut one_way = Vec::with_capacity(2 * ROUNDS as usize);
    let mut next = monotonic_ns();
    for seq in 1..=ROUNDS + WARM_UP {
        run::stop::check(stop)?;
        next += PING_PERIOD_NS;
        sleep_until_ns(next);
        send(&ports, seq, 0)?;
        let mut answered = None;
        while answered.is_none() {
            while let Some(sample) = subscriber.receive().map_err(|e| anyhow!("{e:?}"))? {
                let pong = sample.payload();
                if pong.seq == seq {
                    let latency = monotonic_ns().saturating_sub(pong.publish_ns);
                    answered = Some([pong.ping_latency_ns, latency]);
                }
            }
            if answered.is_none()
                && cleared_and_still_empty(&listener, &subscriber)
                && ipc::wait(&waitset, Duration::from_secs(1))? == ipc::Wake::Timeout
            {
                return Err(anyhow!("no pong for ping {seq} within 1 s"));
            }
        }
        if seq > WARM_UP
            && let Some(latencies) = answered
        {
            one_way.extend(latencies.map(|ns| ns as f64 / 1e3));
        }
    }
    send(&ports, u64::MAX, 0)?;
    let _ = child.0.wait();
    Ok(one_way)
}

/// A child process killed (if still running) and reaped when dropped.
struct KillOnDrop(pub std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            let _ = self.0.kill();
        }
        let _ = self.0.wait();
    }
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cores} × {cpu}, {}", std::env::consts::OS)
}

/// Runs the whole benchmark into `out` (run directories and `bench.json`).
pub fn run(
    out: &Path,
    (realtime_s, swap8_s): (f64, Option<f64>),
    progress: bool,
    stop: &AtomicBool,
) -> anyhow::Result<BenchReport> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let phase = Phases::new(10, progress);
    phase.begin("the raw iceoryx2 ping-pong");
    let raw = raw_ping_pong(stop)?;
    let paper = protocol::Scenario::paper().validated("the paper scenario")?;
    let scenario = paper.with_overrides(&[format!("duration_s={realtime_s}")], "--realtime-s")?;
    let realtime_run =
        |name: &str| local_run(&scenario, &out.join(name), RunMode::Realtime, false, stop);
    phase.begin("the paper in real time");
    let realtime = realtime_run("realtime")?;
    phase.begin("the paper in real time with a live client");
    let live = live::measure(&out.join("live"), &scenario, &realtime, stop)?;
    phase.begin("the paper in process");
    let hot = run::inprocess::run(
        &scenario,
        &out.join("in-process"),
        Recording::files(false),
        stop,
    )?;
    run::stop::check(stop)?;
    phase.begin("the paper in real time, the cores kept awake");
    let awake = awake_cores(&scenario, &out.join("realtime-awake"), &hot, stop)?;
    phase.begin("the paper in lockstep, with run.mcap and without");
    let lockstep = lockstep_pairs(&paper, &out.join("lockstep"), stop)?;
    phase.begin("the cross-host hop against raw Zenoh");
    let cross_host = cross_host::measure(&out.join("cross_host"), &scenario, stop)?;
    run::stop::check(stop)?;
    phase.begin("the MPC step by horizon and obstacle count, and field at N = 30");
    let scaling = scaling::measure(&out.join("scaling"), stop)?;
    let field_n30_step_us = scaling::field_n30(&out.join("field-n30"), stop)?;
    let (moving_obstacles, fleet) = moving_and_fleet(out, &phase, swap8_s, stop)?;
    let processes = realtime
        .processes
        .as_ref()
        .ok_or_else(|| anyhow!("the real-time run reported no processes"))?;
    let mut report = BenchReport {
        machine: machine(),
        raw_iceoryx2_one_way_us: raw,
        pipeline_hop_us: processes.hop_latency_us,
        hop_ratio_p50: processes.hop_latency_us.p50 / raw.p50.max(1e-9),
        sensor_to_actuator_us: processes.loop_latency_us,
        solve_us: realtime.solve_us,
        in_process_solve_us: hot.solve_us,
        realtime_step_ratio_p50: realtime.solve_us.p50 / hot.solve_us.p50.max(1e-9),
        realtime_deadline_misses: realtime.deadline_misses,
        peak_rss_kib: processes.peak_rss_kib.clone(),
        peak_rss_unlocked_kib: lockstep.peak_rss_kib.clone(),
        lockstep_simulated_s: lockstep.simulated_s,
        lockstep_wall_s: lockstep.with_mcap_s,
        lockstep_wall_without_mcap_s: lockstep.without_mcap_s,
        lockstep_speedup: lockstep.simulated_s / lockstep.with_mcap_s.max(1e-9),
        lockstep_recording_share: lockstep.recording_share,
        awake,
        route_planning_us: [5, 20]
            .into_iter()
            .map(|n| (n, route_planning_us(n, PLANNING_FIELDS)))
            .collect(),
        cross_host,
        scaling_growth_p50: (scaling::OBSTACLES.iter())
            .filter_map(|&n| Some((n, scaling::growth(&scaling, n)?)))
            .collect(),
        field_n30_step_us,
        scaling,
        moving_obstacles,
        fleet,
        live,
        targets: Vec::new(),
    };
    report.targets = targets::judge(&report);
    let path = out.join("bench.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(report)
}

/// The costs of moving obstacles and of a fleet ([`scaling::moving_cost`],
/// [`fleet::measure`]).
fn moving_and_fleet(
    out: &Path,
    phase: &Phases,
    swap8_s: Option<f64>,
    stop: &AtomicBool,
) -> anyhow::Result<(scaling::MovingCost, fleet::FleetCost)> {
    phase.begin("the cost of moving obstacles");
    let moving = scaling::moving_cost(&out.join("moving"), stop)?;
    phase.begin("the cost of a fleet");
    Ok((moving, fleet::measure(&out.join("fleet"), swap8_s, stop)?))
}

/// The real-time paper run of `scenario` into `dir` and the raw ping-pong with every core
/// kept awake, against the in-process run `hot`.
fn awake_cores(
    scenario: &Validated,
    dir: &Path,
    hot: &Summary,
    stop: &AtomicBool,
) -> anyhow::Result<AwakeReport> {
    let _awake = run::awake::AwakeCores::start().context("keeping the cores awake")?;
    let raw = raw_ping_pong(stop)?;
    let run = local_run(scenario, dir, RunMode::Realtime, false, stop)?;
    let hops = run
        .processes
        .as_ref()
        .ok_or_else(|| anyhow!("the real-time run reported no processes"))?;
    Ok(AwakeReport {
        raw_iceoryx2_one_way_us: raw,
        pipeline_hop_us: hops.hop_latency_us,
        hop_ratio_p50: hops.hop_latency_us.p50 / raw.p50.max(1e-9),
        sensor_to_actuator_us: hops.loop_latency_us,
        solve_us: run.solve_us,
        realtime_step_ratio_p50: run.solve_us.p50 / hot.solve_us.p50.max(1e-9),
        realtime_deadline_misses: run.deadline_misses,
    })
}

/// The bench's progress on stderr: a line as each phase begins, with the time taken and,
/// from the phases done, an estimate of the time left.
struct Phases {
    count: usize,
    shown: bool,
    begun: std::cell::Cell<usize>,
    started: std::time::Instant,
}

impl Phases {
    fn new(count: usize, shown: bool) -> Phases {
        Phases {
            count,
            shown,
            begun: std::cell::Cell::new(0),
            started: std::time::Instant::now(),
        }
    }

    fn begin(&self, what: &str) {
        let done = self.begun.get();
        self.begun.set(done + 1);
        if !self.shown {
            return;
        }
        let taken = self.started.elapsed().as_secs_f64();
        let left = match done {
            0 => String::new(),
            done => format!(
                ", about {:.0} s left",
                taken / done as f64 * (self.count - done) as f64
            ),
        };
        eprintln!(
            "bench [{}/{}] {what} ({taken:.0} s so far{left})",
            done + 1,
            self.count
        );
    }
}

/// The raw iceoryx2 ping-pong ([`ping_pong`]) on fresh resources, removed after it.
fn raw_ping_pong(stop: &AtomicBool) -> anyhow::Result<Percentiles> {
    let prefix = ipc::new_prefix();
    let raw = ping_pong(&prefix, stop);
    if let Err(e) = ipc::remove_run_resources(&prefix) {
        tracing::warn!("cleaning up the ping-pong: {e}");
    }
    Ok(Percentiles::of(&raw?))
}

/// The lockstep runs' medians (nearest rank), s, and the recording's share.
struct Lockstep {
    /// Peak resident memory of each process of the first run without `run.mcap`, KiB.
    peak_rss_kib: std::collections::BTreeMap<String, u64>,
    simulated_s: f64,
    with_mcap_s: f64,
    without_mcap_s: f64,
    recording_share: f64,
}

/// A run of `scenario` on this host, on fresh iceoryx2 resources, into `dir`.
fn local_run(
    scenario: &protocol::scenario::Validated,
    dir: &Path,
    mode: RunMode,
    mcap: bool,
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    let summary = multiproc::run(
        scenario,
        dir,
        mode,
        &ipc::new_prefix(),
        &multiproc::HostsSetup::default(),
        Recording::files(mcap),
        stop,
    )?;
    run::stop::check(stop)?;
    Ok(summary)
}

/// [`LOCKSTEP_PAIRS`] pairs of lockstep paper runs, with `run.mcap` and without (the
/// recorded one first in even pairs, second in odd ones), into `out/with-mcap-<i>` and
/// `out/without-mcap-<i>`.
fn lockstep_pairs(
    paper: &protocol::scenario::Validated,
    out: &Path,
    stop: &AtomicBool,
) -> anyhow::Result<Lockstep> {
    let mut simulated_s = 0.0;
    let mut peak_rss_kib = std::collections::BTreeMap::new();
    let (mut with, mut without, mut shares) = (Vec::new(), Vec::new(), Vec::new());
    for pair in 0..LOCKSTEP_PAIRS {
        let run = |mcap, name| {
            let dir = out.join(format!("{name}-{pair}"));
            local_run(paper, &dir, RunMode::Lockstep, mcap, stop)
        };
        let (recorded, bare) = if pair % 2 == 0 {
            let recorded = run(true, "with-mcap")?;
            (recorded, run(false, "without-mcap")?)
        } else {
            let bare = run(false, "without-mcap")?;
            (run(true, "with-mcap")?, bare)
        };
        simulated_s = recorded.simulated_s;
        if pair == 0
            && let Some(p) = &bare.processes
        {
            peak_rss_kib = p.peak_rss_kib.clone();
        }
        with.push(recorded.wall_s);
        without.push(bare.wall_s);
        shares.push(recorded.wall_s / bare.wall_s.max(1e-9) - 1.0);
    }
    Ok(Lockstep {
        peak_rss_kib,
        simulated_s,
        with_mcap_s: Percentiles::of(&with).p50,
        without_mcap_s: Percentiles::of(&without).p50,
        recording_share: Percentiles::of(&shares).p50,
    })
}

impl BenchReport {
    pub fn table(&self) -> String {
        let p =
            |x: &Percentiles| format!("p50 {:.1}, p99 {:.1}, max {:.1} µs", x.p50, x.p99, x.max);
        let mib = |rss: &std::collections::BTreeMap<String, u64>| {
            rss.iter()
                .map(|(k, v)| format!("{k} {:.1}", *v as f64 / 1024.0))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let rss = format!(
            "{} (real time, memory locked); {} (lockstep)",
            mib(&self.peak_rss_kib),
            mib(&self.peak_rss_unlocked_kib)
        );
        let planning: String = self
            .route_planning_us
            .iter()
            .map(|(n, q)| format!("  route, {n:>2} discs      {}\n", p(q)))
            .collect();
        let c = &self.cross_host;
        format!(
            "  machine              {}\n  raw iceoryx2 hop     {}\n  pipeline hop         {} ({:.2}× raw at p50)\n  sensor→actuator      {}\n  MPC step             {} ({:.2}× in process at p50: {})\n  deadline misses      {}\n  peak RSS (MiB)       {}\n  lockstep             {:.2} s for {:.0} s ({:.0}× real time) with run.mcap, {:.2} s without (recording {:+.1} %)\n  cores kept awake:\n    raw iceoryx2 hop   {}\n    pipeline hop       {} ({:.2}× raw at p50)\n    sensor→actuator    {}\n    MPC step           {} ({:.2}× in process at p50; {} deadline misses)\n{planning}  raw Zenoh hop        {}\n  cross-host hop       {} ({:.2}× raw Zenoh at p50; round trip {:.0} µs, {} deadline misses)\n",
            self.machine,
            p(&self.raw_iceoryx2_one_way_us),
            p(&self.pipeline_hop_us),
            self.hop_ratio_p50,
            p(&self.sensor_to_actuator_us),
            p(&self.solve_us),
            self.realtime_step_ratio_p50,
            p(&self.in_process_solve_us),
            self.realtime_deadline_misses,
            rss,
            self.lockstep_wall_s,
            self.lockstep_simulated_s,
            self.lockstep_speedup,
            self.lockstep_wall_without_mcap_s,
            100.0 * self.lockstep_recording_share,
            p(&self.awake.raw_iceoryx2_one_way_us),
            p(&self.awake.pipeline_hop_us),
            self.awake.hop_ratio_p50,
            p(&self.awake.sensor_to_actuator_us),
            p(&self.awake.solve_us),
            self.awake.realtime_step_ratio_p50,
            self.awake.realtime_deadline_misses,
            p(&c.raw_zenoh_one_way_us),
            p(&c.cross_host_hop_us),
            c.cross_host_ratio_p50,
            c.link_round_trip_us,
            c.cross_host_deadline_misses
        ) + &scaling::table(&self.scaling)
            + &format!(
                "  field, N = 30        p50 {:.0}, p99 {:.0}, max {:.0} µs\n",
                self.field_n30_step_us.p50, self.field_n30_step_us.p99, self.field_n30_step_us.max
            )
            + &format!(
                "  MPC step, 5 moving / 5 frozen  p50 {:.0} / {:.0} µs ({:.2}×)\n",
                self.moving_obstacles.moving_step_us.p50,
                self.moving_obstacles.frozen_step_us.p50,
                self.moving_obstacles.ratio_p50
            )
            + &self.fleet.table()
            + &format!(
                "  hop, live client     {} ({:.2}× without at p99; {} messages read, {} deadline misses)\n",
                p(&self.live.live_hop_us),
                self.live.live_hop_ratio_p99,
                self.live.live_messages,
                self.live.live_deadline_misses
            )
            + &targets::table(&self.targets)
    }
}
