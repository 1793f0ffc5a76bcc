//! `scmpc run` over iceoryx2: every role as a separate process, launched, clocked and
//! recorded by the orchestrator.
//!
//! Lockstep: the orchestrator grants tick `j` to the plant, and the data flow carries it
//! through estimator, MPC and DFL; the orchestrator records tick `j` (it subscribes to
//! every topic) before it grants `j + 1`, so the recorder is part of the handshake and
//! loses nothing. Real time: the orchestrator publishes the monotonic time of tick 0 and
//! records ticks as they complete, counting every tick it never receives whole.

mod driver;
pub mod fleet;
mod intake;
mod session;
mod supervision;
mod swap_server;

use crate::children::Children;
use crate::remote::RemoteHosts;
use anyhow::{Context, anyhow, bail};
use driver::Driver;
use hosts::net::Security;
use protocol::endpoint::Endpoint;
use protocol::{ControlCommand, Role, Scenario, Validated};
use record::event::{Event, Ready};
use record::judge::Outcome;
use record::{ProcessReport, Recorder, Summary};
use runtime::clock::RunMode;
use runtime::ipc;
use session::Session;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use supervision::ready_role;

/// How long the processes have to report ready.
const READY_TIMEOUT: Duration = Duration::from_secs(10);
/// How long the processes have to exit after the stop command before they are killed.
const STOP_TIMEOUT: Duration = Duration::from_secs(2);
/// Lockstep: a tick that makes no progress for this long means a process hung.
const TICK_TIMEOUT: Duration = Duration::from_secs(10);
/// Real time: lead time between the start command and tick 0.
const START_LEAD: Duration = Duration::from_millis(100);
/// How often the orchestrator looks at its children and the stop flag while waiting.
const POLL: Duration = Duration::from_millis(20);
/// How often the orchestrator checks that the processes of the run's nodes are alive.
const NODE_SCAN: Duration = Duration::from_millis(50);
/// How often it lists the run's nodes anew (and when one of their processes died).
const NODE_LISTING: Duration = Duration::from_secs(1);
/// A replacement is warm once it has published outputs spanning this many samples.
const SWAP_WARMUP_SAMPLES: u64 = 2;
/// A warm replacement takes over at the first sample boundary at least this many samples
/// ahead, so every process has heard of the switch before its tick.
const SWITCH_LEAD_SAMPLES: u64 = 2;

/// `run.json` of a run directory: how tools such as `scmpc swap` reach the running run.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct RunInfo {
    pub iceoryx2_prefix: String,
    pub orchestrator_pid: u32,
    pub mode: String,
    /// The iceoryx2 id of the publisher of swap replies (hexadecimal): `scmpc swap`
    /// takes answers from it alone.
    pub swap_reply_publisher: String,
}

impl RunInfo {
    pub const FILE: &'static str = "run.json";

    fn write(&self, dir: &Path) -> anyhow::Result<()> {
        let path = dir.join(Self::FILE);
        std::fs::write(&path, serde_json::to_string_pretty(self)? + "\n")
            .with_context(|| format!("writing {}", path.display()))
    }

    pub fn read(dir: &Path) -> anyhow::Result<RunInfo> {
        let path = dir.join(Self::FILE);
        let text = std::fs::read_to_string(&path).with_context(|| {
            format!(
                "reading {} (is it the directory of a multi-process run?)",
                path.display()
            )
        })?;
        serde_json::from_str(&text)
            .with_context(|| format!("{}: not a run description", path.display()))
    }
}

/// Where the other hosts of a run listen, and how the links to them are secured
/// (docs/hosts.md).
#[derive(Debug, Clone, Default)]
pub struct HostsSetup {
    pub endpoints: BTreeMap<String, Endpoint>,
    pub security: Security,
}

/// What the processes need beyond the run's environment: the TLS files of the robot's
/// router for the robot process of `plant.kind = "ros2"` (docs/ros2.md).
fn robot_env(scenario: &Validated, security: &Security) -> Vec<(String, String)> {
    match scenario.plant.kind {
        protocol::PlantKind::Ros2 => security.to_env(),
        protocol::PlantKind::Sim => Vec::new(),
    }
}

/// Runs the scenario as role processes on iceoryx2 resources named with `prefix` (roles
/// placed on other hosts there, as `hosts` says) and writes `out`. Whatever happens, every process is stopped
/// and the run's iceoryx2 resources are removed before this returns.
pub fn run(
    scenario: &Validated,
    out: &Path,
    mode: RunMode,
    prefix: &str,
    hosts: &HostsSetup,
    recording: crate::sinks::Recording,
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    remove_dead_runs();
    let mut recorder = crate::sinks::recorder(scenario, out, recording)?;
    ipc::register_run(prefix, out).context("registering the run")?;
    let clock = Clocking {
        mode,
        pace: crate::pace::Pace::of(scenario, recording),
    };
    let result = drive(scenario, out, clock, prefix, hosts, stop, &mut recorder);
    if let Err(e) = ipc::end_run(prefix) {
        tracing::warn!("cleaning up the run's iceoryx2 resources: {e}");
    }
    let (outcome, mut report) = result?;
    report.leftover_files = ipc::leftover_files(prefix)
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    Ok(recorder.finish(
        scenario,
        mode.as_str(),
        outcome,
        started.elapsed().as_secs_f64(),
        Some(report),
        crate::stop::received(),
    )?)
}

/// The run's hosts, their agents connected and their joining recorded (`None`: every role
/// on this host).
fn connect_hosts(
    scenario: &Validated,
    mode: RunMode,
    prefix: &str,
    hosts: &HostsSetup,
    session: &Session,
    recorder: &mut Recorder,
) -> anyhow::Result<Option<RemoteHosts>> {
    if scenario.hosts.names().is_empty() {
        return Ok(None);
    }
    let remote = RemoteHosts::connect(
        scenario,
        mode,
        prefix,
        crate::remote::Whose {
            robot: session.robot(),
            fleet: None,
        },
        &hosts.endpoints,
        &hosts.security,
        session.control.publisher_id(),
    )?;
    record_joined(&remote, recorder)?;
    Ok(Some(remote))
}

/// Each host's joining, as a `host_joined` event.
fn record_joined(remote: &RemoteHosts, recorder: &mut Recorder) -> anyhow::Result<()> {
    for (name, link) in &remote.hosts {
        recorder.event(Event::HostJoined {
            host: name.clone(),
            endpoint: link.endpoint.clone(),
            agent_pid: link.agent_pid,
            prefix: link.prefix.clone(),
            round_trip_us: link.clock.round_trip_ns as f64 / 1e3,
            clock_correction_ms: link.clock.correction_ns as f64 / 1e6,
        })?;
    }
    Ok(())
}

/// Ends the run on the other hosts; what the orchestrator's bridge and each link carried.
fn end_hosts(
    remote: &RemoteHosts,
) -> (
    Option<hosts::LinkCounters>,
    BTreeMap<String, record::LinkReport>,
) {
    let mut counters = remote.end();
    let orchestrator_bridge = counters.remove(hosts::keys::ORCHESTRATOR);
    (orchestrator_bridge, link_reports(remote, counters))
}

/// The pids and hosts of the processes spawned, each recorded as an event.
fn spawned_report(
    prefix: &str,
    children: &Children,
    recorder: &mut Recorder,
) -> anyhow::Result<ProcessReport> {
    let mut report = ProcessReport {
        iceoryx2_prefix: prefix.to_string(),
        ..ProcessReport::default()
    };
    report
        .pids
        .insert("orchestrator".into(), std::process::id());
    for p in &children.list {
        report.pids.insert(p.role.as_str().into(), p.pid());
        if let Some(host) = p.host() {
            report.hosts.insert(p.role.as_str().into(), host.into());
        }
        recorder.event(Event::Spawned {
            role: p.role,
            pid: p.pid(),
            host: p.host().map(String::from),
        })?;
    }

    Ok(report)
}

/// How a run is clocked: lockstep or real time, and lockstep held to real time for a live
/// view (`live.pace`).
struct Clocking {
    mode: RunMode,
    pace: Option<crate::pace::Pace>,
}

/// Launches the processes, clocks and records the run, and stops the processes. Every
/// iceoryx2 port of the orchestrator is gone when this returns.
fn drive(
    scenario: &Validated,
    out: &Path,
    clock: Clocking,
    prefix: &str,
    hosts: &HostsSetup,
    stop: &AtomicBool,
    recorder: &mut Recorder,
) -> anyhow::Result<(Outcome, ProcessReport)> {
    let Clocking { mode, pace } = clock;
    let session = Session::open(prefix, scenario, mode)?;
    RunInfo {
        iceoryx2_prefix: prefix.to_string(),
        orchestrator_pid: std::process::id(),
        mode: mode.as_str().to_string(),
        swap_reply_publisher: format!("{:x}", session.swap_replies.publisher_id()),
    }
    .write(out)?;
    let remote = connect_hosts(scenario, mode, prefix, hosts, &session, recorder)?;
    let mut children = Children::new(
        &out.join("scenario.toml"),
        prefix,
        session.robot(),
        mode,
        session.control.publisher_id(),
        robot_env(scenario, &hosts.security),
        remote,
    )?
    .with_logs(&out.join(crate::children::LOG_DIR));
    children.spawn_all(scenario.roles())?;
    let mut report = spawned_report(prefix, &children, recorder)?;
    // Real time: the orchestrator's recording at its tier, below every role, for as long as
    // the run lasts.
    let _recording_tier = (mode == RunMode::Realtime)
        .then(|| crate::scheduling::orchestrator(&scenario.realtime))
        .flatten();

    // Lockstep: the orchestrator is part of the handshake and wakes on every sample. Real
    // time: it only records, so it drains its buffers every POLL instead of competing for
    // the CPU with the control loop at every tick.
    let waitset = ipc::waitset(false)?;
    let mut guards = vec![session.status.attach(&waitset)?];
    if mode == RunMode::Lockstep {
        for input in session.inputs().filter(|i| i.listener().is_some()) {
            guards.push(ipc::attach_input(&waitset, input)?);
        }
    }
    let outcome =
        wait_until_ready(scenario, &session, &waitset, &mut children, stop).and_then(|()| {
            recorder.event(Event::Ready(Ready::Run {
                iceoryx2_prefix: prefix.to_string(),
            }))?;
            if mode == RunMode::Realtime {
                report.scheduling = scheduling_report(&children);
            }
            let mut driver = Driver::new(scenario, &session, &mut children, recorder, stop);
            driver.pace = pace;
            let outcome = match mode {
                RunMode::Lockstep => driver.lockstep(&waitset),
                RunMode::Realtime => driver.realtime(&waitset),
            };
            driver.finish(outcome, &mut report)
        });
    // Peak resident memory of every process still running, then stop them all whatever
    // happened, then release the orchestrator's own ports.
    record_peak_rss(&children, &mut report);
    let _ = session.command(ControlCommand::Stop);
    record_exits(recorder, children.shut_down(STOP_TIMEOUT))?;
    if let Some(remote) = &children.remote {
        (report.orchestrator_bridge, report.links) = end_hosts(remote);
    }
    drop(guards);
    Ok((outcome?, report))
}

/// Each process's exit ([`Children::shut_down`]), as an `exited` event.
fn record_exits(
    recorder: &mut Recorder,
    exits: Vec<(Role, u32, String, bool)>,
) -> anyhow::Result<()> {
    for (role, epoch, status, killed) in exits {
        recorder.event(Event::Exited {
            role,
            epoch,
            status,
            killed,
        })?;
    }
    Ok(())
}

/// Each link to another host, with what its host's bridge carried (`counters`, by host).
fn link_reports(
    remote: &RemoteHosts,
    mut counters: BTreeMap<String, hosts::LinkCounters>,
) -> BTreeMap<String, record::LinkReport> {
    remote
        .hosts
        .iter()
        .map(|(name, link)| {
            let report = record::LinkReport {
                endpoint: link.endpoint.clone(),
                round_trip_us: link.clock.round_trip_ns as f64 / 1e3,
                clock_correction_ms: link.clock.correction_ns as f64 / 1e6,
                clock_uncertainty_us: link.clock.uncertainty_ns() as f64 / 1e3,
                host_bridge: counters.remove(name),
                lost: remote.is_lost(name),
            };
            (name.clone(), report)
        })
        .collect()
}

/// How every process on this host runs, once ready, by role (and `orchestrator`).
fn scheduling_report(children: &Children) -> BTreeMap<String, record::Scheduling> {
    let local = children.list.iter().filter(|p| p.host().is_none());
    local
        .map(|p| (p.role.as_str().to_string(), p.pid()))
        .chain([("orchestrator".to_string(), std::process::id())])
        .filter_map(|(name, pid)| Some((name, crate::scheduling::observe(pid)?)))
        .collect()
}

/// The peak resident memory of every process still running and of the orchestrator.
fn record_peak_rss(children: &Children, report: &mut ProcessReport) {
    for p in children.list.iter().filter(|p| p.host().is_none()) {
        if let Some(kib) = peak_rss_kib(p.pid()) {
            let peak = report
                .peak_rss_kib
                .entry(p.role.as_str().into())
                .or_default();
            *peak = (*peak).max(kib);
        }
    }
    if let Some(kib) = peak_rss_kib(std::process::id()) {
        report.peak_rss_kib.insert("orchestrator".into(), kib);
    }
}

/// Peak resident set size of process `pid` (`VmHWM`), KiB.
fn peak_rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Waits until every role has reported ready.
fn wait_until_ready(
    scenario: &Scenario,
    session: &Session,
    waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    children: &mut Children,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let deadline = Instant::now() + READY_TIMEOUT;
    let mut ready = [false; Role::COUNT];
    while !scenario.roles().all(|r| ready[r as usize]) {
        if let Some((p, status)) = children.take_exited() {
            bail!(
                "the {} process exited before it was ready ({status})",
                p.role.as_str()
            );
        }
        if stop.load(Ordering::Relaxed) {
            bail!("interrupted while starting");
        }
        if Instant::now() > deadline {
            let missing: Vec<&str> = scenario
                .roles()
                .filter(|r| !ready[*r as usize])
                .map(|r| r.as_str())
                .collect();
            return Err(anyhow!(
                "no ready report within {READY_TIMEOUT:?} from: {}",
                missing.join(", ")
            ));
        }
        ipc::wait(waitset, POLL)?;
        let mut joined = Vec::new();
        session.status.drain(|s, _| joined.extend(ready_role(&s)))?;
        for (role, s) in joined {
            ready[role as usize] = true;
            let epoch = s.header.epoch;
            session.pin(role, epoch, children.pins(role, epoch, s.publishers))?;
        }
    }
    Ok(())
}

/// Removes the iceoryx2 resources of runs on this machine whose orchestrator (or agent) is
/// dead, as every run and every agent does when it starts.
pub fn remove_dead_runs() {
    for stale in ipc::stale_run_prefixes() {
        match ipc::remove_run(&stale) {
            Ok(()) => tracing::info!("removed the iceoryx2 resources of dead run `{stale}`"),
            Err(e) => tracing::warn!("cannot remove the resources of dead run `{stale}`: {e}"),
        }
    }
}
