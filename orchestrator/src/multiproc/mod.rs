//! `scmpc run` over iceoryx2: the four roles as separate processes, launched, clocked and
//! recorded by the orchestrator.
//!
//! Lockstep: the orchestrator grants tick `j` to the plant, and the data flow carries it
//! through estimator, MPC and DFL; the orchestrator records tick `j` (it subscribes to
//! every topic) before it grants `j + 1`, so the recorder is part of the handshake and
//! loses nothing. Real time: the orchestrator publishes the monotonic time of tick 0 and
//! records ticks as they complete, counting every tick it never receives whole.

mod children;
mod clock;
mod receive;
mod status_line;
mod supervision;
mod swap_server;

use crate::monitor::Outcome;
use crate::record::{Latencies, ProcessReport, Recorder, Summary};
use anyhow::{Context, anyhow, bail};
use children::Children;
use protocol::clock::{monotonic_ns, tick_at};
use protocol::ipc::{self, Input, Receiver, Sender, open_topic};
use protocol::runtime::RunMode;
use protocol::{
    Actuation, Control, ControlCommand, DeadlineVerdict, EpochSchedule, Estimate, GroundTruth,
    Header, Measurement, Plan, Rejection, RestartPolicy, Role, Route, Scenario, Status,
    StatusEvent, SwapReply, SwapRequest, Validated,
};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use supervision::Blame;
use swap_server::{PendingSwap, Swap, scheduled_swaps};

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
/// A replacement not warm this long after it was started is stopped; the swap fails.
const SWAP_TIMEOUT: Duration = Duration::from_secs(10);

/// Environment of every role process the orchestrator starts (README, "Supervision"): a
/// replacement command needs nothing else to join the run.
pub const ENV_SCENARIO: &str = "SCMPC_SCENARIO";
pub const ENV_PREFIX: &str = "SCMPC_PREFIX";
/// `lockstep` or `realtime`.
pub const ENV_MODE: &str = "SCMPC_MODE";
/// The producer epoch the process must stamp on every sample.
pub const ENV_EPOCH: &str = "SCMPC_EPOCH";
/// `plant`, `estimator`, `mpc` or `dfl`.
pub const ENV_ROLE: &str = "SCMPC_ROLE";
/// The orchestrator's pid: a role process stops the robot and exits when it is gone.
pub const ENV_SUPERVISOR: &str = "SCMPC_SUPERVISOR_PID";
/// The iceoryx2 id of the orchestrator's control publisher (hexadecimal): a role process
/// takes control messages from it alone.
pub const ENV_CONTROL_PUBLISHER: &str = "SCMPC_CONTROL_PUBLISHER";

fn mode_name(mode: RunMode) -> &'static str {
    match mode {
        RunMode::Lockstep => "lockstep",
        RunMode::Realtime => "realtime",
    }
}

/// Everything received for one tick.
#[derive(Default)]
struct TickSlot {
    truth: Option<GroundTruth>,
    measurement: Option<Measurement>,
    estimate: Option<Estimate>,
    /// With the orchestrator's own receipt latency, ns.
    actuation: Option<(Actuation, u64)>,
}

impl TickSlot {
    fn complete(&self) -> bool {
        self.truth.is_some()
            && self.measurement.is_some()
            && self.estimate.is_some()
            && self.actuation.is_some()
    }
}

/// The slot of `tick`, unless the tick is already recorded (`tick < cursor`).
fn slot(slots: &mut BTreeMap<u64, TickSlot>, cursor: u64, tick: u64) -> Option<&mut TickSlot> {
    (tick >= cursor).then(|| slots.entry(tick).or_default())
}

/// The orchestrator's ports.
struct Session {
    control: Sender<Control>,
    status: Receiver<Status>,
    truth: Receiver<GroundTruth>,
    measurement: Receiver<Measurement>,
    estimate: Receiver<Estimate>,
    plan: Receiver<Plan>,
    actuation: Receiver<Actuation>,
    deadline: Receiver<DeadlineVerdict>,
    route: Receiver<Route>,
    /// Live requests of `scmpc swap`, and the answers.
    swap_requests: Receiver<SwapRequest>,
    swap_replies: Sender<SwapReply>,
    /// Which producer of each role is taken, announced with every control message.
    schedule: std::cell::Cell<EpochSchedule>,
    /// The run's clock as the orchestrator keeps it; its inputs are bound by it.
    clock: Rc<RunClock>,
    /// The node of the ports above; declared last, so it is dropped after them.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

/// The orchestrator's clock, which bounds the ticks its inputs accept: in lockstep the
/// tick granted last, in real time the wall clock's tick plus [`ipc::TICK_SLACK`].
struct RunClock {
    mode: RunMode,
    dt_s: f64,
    granted: std::cell::Cell<Option<u64>>,
    start_ns: std::cell::Cell<Option<u64>>,
}

impl ipc::TickLimit for RunClock {
    fn newest_tick(&self, _refresh: bool) -> Option<u64> {
        match self.mode {
            RunMode::Lockstep => self.granted.get(),
            RunMode::Realtime => (self.start_ns.get())
                .map(|start| tick_at(start, monotonic_ns(), self.dt_s) + ipc::TICK_SLACK),
        }
    }

    fn dt_s(&self) -> f64 {
        self.dt_s
    }
}

impl Session {
    fn open(prefix: &str, mode: RunMode, dt_s: f64) -> Result<Session, ipc::IpcError> {
        let node = ipc::create_node(prefix, "orchestrator", false)?;
        let session = Session {
            control: open_topic(&node, ipc::CONTROL)?.sender(0)?,
            status: open_topic(&node, ipc::STATUS)?.receiver()?,
            truth: open_topic(&node, ipc::TRUTH)?.receiver_from(Role::Plant)?,
            measurement: open_topic(&node, ipc::MEASUREMENT)?.receiver_from(Role::Plant)?,
            estimate: open_topic(&node, ipc::ESTIMATE)?.receiver_from(Role::Estimator)?,
            plan: open_topic(&node, ipc::PLAN)?.receiver_from(Role::Mpc)?,
            actuation: open_topic(&node, ipc::ACTUATION)?.receiver_from(Role::Dfl)?,
            deadline: open_topic(&node, ipc::DEADLINE)?.receiver_from(Role::Dfl)?,
            route: open_topic(&node, ipc::ROUTE)?.receiver_from(Role::Planner)?,
            swap_requests: open_topic(&node, ipc::SWAP)?.receiver()?,
            swap_replies: open_topic(&node, ipc::SWAP_REPLY)?.sender(0)?,
            schedule: std::cell::Cell::new(EpochSchedule::default()),
            clock: Rc::new(RunClock {
                mode,
                dt_s,
                granted: std::cell::Cell::new(None),
                start_ns: std::cell::Cell::new(None),
            }),
            _node: node,
        };
        for input in session.inputs() {
            input.bound_by(session.clock.clone());
            input.follow(EpochSchedule::default());
        }
        Ok(session)
    }

    /// Sends `command` with the schedule and, in its header, the tick granted last (a
    /// process's clock in lockstep): `tick` for a grant.
    fn command(
        &self,
        command: ControlCommand,
        tick: u64,
        start_ns: u64,
    ) -> Result<(), ipc::IpcError> {
        match command {
            ControlCommand::Grant => self.clock.granted.set(Some(tick)),
            ControlCommand::Start => self.clock.start_ns.set(Some(start_ns)),
            _ => {}
        }
        self.control.send(Control {
            header: Header {
                tick: self.clock.granted.get().unwrap_or(0),
                ..Header::default()
            },
            command: command as u32,
            start_ns,
            epochs: self.schedule.get(),
            ..Control::default()
        })
    }

    /// The orchestrator's inputs, for housekeeping.
    fn inputs(&self) -> [&dyn Input; 7] {
        [
            &self.truth,
            &self.measurement,
            &self.estimate,
            &self.plan,
            &self.actuation,
            &self.deadline,
            &self.route,
        ]
    }

    /// Changes the epoch schedule, for the orchestrator and every process.
    fn reschedule(&self, change: impl FnOnce(&mut EpochSchedule)) -> Result<(), ipc::IpcError> {
        let mut schedule = self.schedule.get();
        change(&mut schedule);
        self.schedule.set(schedule);
        for input in self.inputs() {
            input.follow(schedule);
        }
        self.command(ControlCommand::Epochs, 0, 0)
    }

    /// Pins the outputs of the process that sent the ready report `s` to the publishers it
    /// announced, once per epoch (README, "Supervision"), and tells every process.
    fn pin(&self, role: Role, s: &Status) -> Result<(), ipc::IpcError> {
        let mut schedule = self.schedule.get();
        if schedule.pin(role, s.header.epoch, s.publishers) {
            self.reschedule(|now| *now = schedule)?;
        }
        Ok(())
    }

    /// The orchestrator's input carrying the output of `role`: how it sees a replacement
    /// warm up.
    fn output_of(&self, role: Role) -> &dyn Input {
        match role {
            Role::Plant => &self.truth,
            Role::Estimator => &self.estimate,
            Role::Mpc => &self.plan,
            Role::Dfl => &self.actuation,
            Role::Planner => &self.route,
        }
    }

    /// Samples the orchestrator itself refused since the last call: (producer, rejection
    /// code, count).
    fn take_rejections(&self) -> Vec<(Option<Role>, u32, u64)> {
        let mut refused = Vec::new();
        for input in self.inputs() {
            for (code, count) in input.take_rejections().into_iter().enumerate() {
                if count > 0 {
                    refused.push((input.producer(), code as u32, count));
                }
            }
        }
        refused
    }
}

/// The state of a run while it is driven.
struct Driver<'a> {
    scenario: &'a Scenario,
    mode: RunMode,
    session: &'a Session,
    children: &'a mut Children,
    recorder: &'a mut Recorder,
    latencies: Latencies,
    slots: BTreeMap<u64, TickSlot>,
    plans: BTreeMap<u64, Plan>,
    verdicts: BTreeMap<u64, DeadlineVerdict>,
    /// Routes received and not recorded yet, in arrival order.
    routes: Vec<Route>,
    newest_truth: Option<u64>,
    stop: &'a AtomicBool,
    start_ns: u64,
    record_gaps: u64,
    restarts: u32,
    /// Samples refused by any consumer, by reason.
    rejected: BTreeMap<String, u64>,
    /// Per role: since when its own samples have been refused, with the epoch refused and
    /// how many of its samples the orchestrator had taken then ([`Driver::contain`]).
    blamed: [Option<Blame>; Role::COUNT],
    /// The epoch the next started process gets.
    next_epoch: u32,
    /// Next tick to record (every earlier one is recorded).
    cursor: u64,
    /// Swaps not started yet, earliest first: the scenario's, and live requests (time 0).
    scheduled: Vec<PendingSwap>,
    swaps: Vec<Swap>,
    swaps_done: u32,
    ticks_without_estimate: u64,
    /// Newest sample whose plan is recorded.
    last_plan: Option<u64>,
    last_node_scan: Instant,
    /// `None`: list at the next scan (a process has just joined).
    last_node_listing: Option<Instant>,
    /// Processes of the run's living nodes, as last listed.
    node_pids: Vec<u32>,
    status_line: status_line::StatusLine,
    /// Sensor to actuator of the newest tick recorded that has one, ns.
    last_sensor_to_actuator_ns: Option<u64>,
}

impl<'a> Driver<'a> {
    fn new(
        scenario: &'a Scenario,
        mode: RunMode,
        session: &'a Session,
        children: &'a mut Children,
        recorder: &'a mut Recorder,
        stop: &'a AtomicBool,
    ) -> Driver<'a> {
        Driver {
            scenario,
            mode,
            session,
            children,
            recorder,
            latencies: Latencies::default(),
            slots: BTreeMap::new(),
            plans: BTreeMap::new(),
            verdicts: BTreeMap::new(),
            routes: Vec::new(),
            newest_truth: None,
            stop,
            start_ns: 0,
            record_gaps: 0,
            restarts: 0,
            rejected: BTreeMap::new(),
            blamed: [None; Role::COUNT],
            next_epoch: 0,
            cursor: 0,
            scheduled: scheduled_swaps(scenario),
            swaps: Vec::new(),
            swaps_done: 0,
            ticks_without_estimate: 0,
            last_plan: None,
            last_node_scan: Instant::now(),
            last_node_listing: None,
            node_pids: Vec::new(),
            status_line: status_line::StatusLine::new(),
            last_sensor_to_actuator_ns: None,
        }
    }

    /// Redraws the status line on a terminal, when due.
    fn show_status(&mut self) {
        let (recorder, duration_s) = (&*self.recorder, self.scenario.duration_s);
        let latency = self.last_sensor_to_actuator_ns;
        self.status_line.update(|| status_line::Live {
            t_s: recorder.simulated_s(),
            duration_s,
            deadline_misses: recorder.deadline_misses(),
            sensor_to_actuator_us: latency.map(|ns| ns as f64 / 1e3),
            clearance_m: recorder.last_clearance_m(),
            mode: recorder.last_mode().map_or("-", |m| m.as_str()),
        });
    }

    /// After the clock has stopped with `outcome`: records the plans still held, answers
    /// every swap that did not happen, and fills `report` with the run's counts.
    fn finish(
        mut self,
        outcome: anyhow::Result<Outcome>,
        report: &mut ProcessReport,
    ) -> anyhow::Result<Outcome> {
        self.status_line.clear();
        let outcome = outcome.and_then(|o| self.record_plans().map(|_| o));
        for swap in std::mem::take(&mut self.swaps) {
            self.fail_swap(swap, "the run ended before the switch")?;
        }
        for pending in std::mem::take(&mut self.scheduled) {
            if let Some(asker) = pending.request {
                self.reply(asker, None, "the run ended before the swap could start")?;
            }
        }
        self.latencies.report(report);
        report.record_gaps = self.record_gaps;
        report.ticks_without_estimate = self.ticks_without_estimate;
        report.restarts = self.restarts;
        report.swaps = self.swaps_done;
        report.rejected_samples = std::mem::take(&mut self.rejected);
        outcome
    }
}

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

/// Runs the scenario as four processes on iceoryx2 resources named with `prefix` and
/// writes `out`. Whatever happens, every process is stopped
/// and the run's iceoryx2 resources are removed before this returns.
pub fn run(
    scenario: &Validated,
    out: &Path,
    mode: RunMode,
    prefix: &str,
    mcap: bool,
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    for stale in ipc::stale_run_prefixes() {
        match ipc::remove_run_resources(&stale) {
            Ok(()) => {
                ipc::unregister_run(&stale);
                tracing::info!("removed the iceoryx2 resources of dead run `{stale}`")
            }
            Err(e) => tracing::warn!("cannot remove the resources of dead run `{stale}`: {e}"),
        }
    }
    let mut recorder =
        Recorder::create(out, scenario).with_context(|| format!("creating {}", out.display()))?;
    if mcap {
        recorder
            .record_mcap(scenario)
            .context("creating run.mcap")?;
    }
    ipc::register_run(prefix).context("registering the run")?;
    let result = drive(scenario, out, mode, prefix, stop, &mut recorder);
    match ipc::remove_run_resources(prefix) {
        Ok(()) => ipc::unregister_run(prefix),
        Err(e) => tracing::warn!("cleaning up the run's iceoryx2 resources: {e}"),
    }
    let (outcome, mut report) = result?;
    report.leftover_files = ipc::leftover_files(prefix)
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    Ok(recorder.finish(
        scenario,
        mode_name(mode),
        outcome,
        started.elapsed().as_secs_f64(),
        Some(report),
    )?)
}

/// Launches the processes, clocks and records the run, and stops the processes. Every
/// iceoryx2 port of the orchestrator is gone when this returns.
fn drive(
    scenario: &Scenario,
    out: &Path,
    mode: RunMode,
    prefix: &str,
    stop: &AtomicBool,
    recorder: &mut Recorder,
) -> anyhow::Result<(Outcome, ProcessReport)> {
    let session = Session::open(prefix, mode, scenario.timing.dt_s())?;
    RunInfo {
        iceoryx2_prefix: prefix.to_string(),
        orchestrator_pid: std::process::id(),
        mode: mode_name(mode).to_string(),
        swap_reply_publisher: format!("{:x}", session.swap_replies.publisher_id()),
    }
    .write(out)?;
    let mut children = Children::spawn(
        &out.join("scenario.toml"),
        scenario.roles(),
        prefix,
        mode,
        session.control.publisher_id(),
    )?;
    let mut report = ProcessReport {
        iceoryx2_prefix: prefix.to_string(),
        ..ProcessReport::default()
    };
    report
        .pids
        .insert("orchestrator".into(), std::process::id());
    for p in &children.list {
        report.pids.insert(p.role.as_str().into(), p.child.id());
        recorder.event(
            "spawned",
            serde_json::json!({ "role": p.role.as_str(), "pid": p.child.id() }),
        )?;
    }

    // Lockstep: the orchestrator is part of the handshake and wakes on every sample. Real
    // time: it only records, so it drains its buffers every POLL instead of competing for
    // the CPU with the control loop at every tick.
    let waitset = ipc::waitset(false)?;
    let mut guards = vec![session.status.attach(&waitset)?];
    if mode == RunMode::Lockstep {
        guards.push(session.truth.attach(&waitset)?);
        guards.push(session.measurement.attach(&waitset)?);
        guards.push(session.estimate.attach(&waitset)?);
        guards.push(session.plan.attach(&waitset)?);
        guards.push(session.actuation.attach(&waitset)?);
        guards.push(session.deadline.attach(&waitset)?);
        guards.push(session.route.attach(&waitset)?);
    }
    let outcome =
        wait_until_ready(scenario, &session, &waitset, &mut children, stop).and_then(|()| {
            recorder.event("ready", serde_json::json!({ "iceoryx2_prefix": prefix }))?;
            let mut driver = Driver::new(scenario, mode, &session, &mut children, recorder, stop);
            let outcome = match mode {
                RunMode::Lockstep => driver.lockstep(&waitset),
                RunMode::Realtime => driver.realtime(&waitset),
            };
            driver.finish(outcome, &mut report)
        });
    // Peak resident memory of every process still running, then stop them all whatever
    // happened, then release the orchestrator's own ports.
    record_peak_rss(&children, &mut report);
    let _ = session.command(ControlCommand::Stop, 0, 0);
    for (role, epoch, status, killed) in children.shut_down(STOP_TIMEOUT) {
        recorder.event(
            "exited",
            serde_json::json!({ "role": role.as_str(), "epoch": epoch, "status": status, "killed": killed }),
        )?;
    }
    drop(guards);
    Ok((outcome?, report))
}

/// The peak resident memory of every process still running and of the orchestrator.
fn record_peak_rss(children: &Children, report: &mut ProcessReport) {
    for p in &children.list {
        if let Some(kib) = peak_rss_kib(p.child.id()) {
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

/// The role of a ready report.
fn ready_role(s: &Status) -> Option<(Role, Status)> {
    (s.event == StatusEvent::Ready as u32)
        .then(|| Role::from_code(s.role))
        .flatten()
        .map(|role| (role, *s))
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
            session.pin(role, &s)?;
        }
    }
    Ok(())
}
