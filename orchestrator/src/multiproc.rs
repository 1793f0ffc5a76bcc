//! `scmpc run` over iceoryx2: the four roles as separate processes, launched, clocked and
//! recorded by the orchestrator.
//!
//! Lockstep: the orchestrator grants tick `j` to the plant, and the data flow carries it
//! through estimator, MPC and DFL; the orchestrator records tick `j` (it subscribes to
//! every topic) before it grants `j + 1`, so the recorder is part of the handshake and
//! loses nothing. Real time: the orchestrator publishes the monotonic time of tick 0 and
//! records ticks as they complete, counting every tick it never receives whole.

use crate::monitor::Outcome;
use crate::record::{Latencies, ProcessReport, Recorder, Summary};
use anyhow::{Context, anyhow, bail};
use protocol::clock::monotonic_ns;
use protocol::ipc::{self, Input, Receiver, RunMode, Sender, open_topic};
use protocol::{
    Actuation, Control, ControlCommand, DeadlineVerdict, EpochSchedule, Estimate, GroundTruth,
    Header, Measurement, Plan, Rejection, RestartPolicy, Role, Scenario, Status, StatusEvent,
    SwapReply, SwapRequest,
};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

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

/// Environment of every role process the orchestrator starts (DESIGN.md section 5): a
/// replacement command needs nothing else to join the run.
pub const ENV_SCENARIO: &str = "SCMPC_SCENARIO";
pub const ENV_PREFIX: &str = "SCMPC_PREFIX";
/// `lockstep` or `realtime`.
pub const ENV_MODE: &str = "SCMPC_MODE";
/// The producer epoch the process must stamp on every sample.
pub const ENV_EPOCH: &str = "SCMPC_EPOCH";
/// `plant`, `estimator`, `mpc` or `dfl`.
pub const ENV_ROLE: &str = "SCMPC_ROLE";

/// One process the orchestrator started.
struct Proc {
    role: Role,
    epoch: u32,
    child: Child,
    /// Set when the process is being stopped on purpose (replaced): its exit is not a
    /// crash, and it is killed if still alive at this instant.
    retire_by: Option<Instant>,
}

/// The run's processes; killed and reaped on drop whatever happened.
struct Children {
    exe: std::path::PathBuf,
    scenario_file: std::path::PathBuf,
    prefix: String,
    mode: &'static str,
    list: Vec<Proc>,
}

impl Children {
    fn spawn(scenario_file: &Path, prefix: &str, mode: RunMode) -> anyhow::Result<Children> {
        let mut children = Children {
            exe: std::env::current_exe().context("locating the scmpc executable")?,
            scenario_file: scenario_file.to_path_buf(),
            prefix: prefix.to_string(),
            mode: mode_name(mode),
            list: Vec::new(),
        };
        for role in Role::ALL {
            children.spawn_role(role, 0, &[])?;
        }
        Ok(children)
    }

    /// Starts a process for `role` with producer epoch `epoch`: `command` (program and
    /// arguments; a program named `scmpc` is this executable), or the built-in role
    /// process when it is empty. Returns its pid.
    fn spawn_role(&mut self, role: Role, epoch: u32, command: &[String]) -> anyhow::Result<u32> {
        let builtin = [role.as_str().to_string()];
        let (program, args) = match command.split_first() {
            None => (self.exe.as_os_str(), &builtin[..]),
            Some((p, args)) if p == "scmpc" => (self.exe.as_os_str(), args),
            Some((p, args)) => (std::ffi::OsStr::new(p), args),
        };
        let child = Command::new(program)
            .args(args)
            .env(ENV_SCENARIO, &self.scenario_file)
            .env(ENV_PREFIX, &self.prefix)
            .env(ENV_MODE, self.mode)
            .env(ENV_EPOCH, epoch.to_string())
            .env(ENV_ROLE, role.as_str())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| {
                format!(
                    "starting the {} process `{}`",
                    role.as_str(),
                    program.to_string_lossy()
                )
            })?;
        let pid = child.id();
        self.list.push(Proc {
            role,
            epoch,
            child,
            retire_by: None,
        });
        Ok(pid)
    }

    fn pid(&self, role: Role, epoch: u32) -> Option<u32> {
        self.list
            .iter()
            .find(|p| p.role == role && p.epoch == epoch)
            .map(|p| p.child.id())
    }

    /// Asks the process of `role` and `epoch` to exit (SIGTERM; a role process leaves its
    /// loop and closes its ports), and kills it after `grace`.
    fn retire(&mut self, role: Role, epoch: u32, grace: Duration) {
        if let Some(p) = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)
        {
            p.retire_by = Some(Instant::now() + grace);
            if let Ok(pid) = libc::pid_t::try_from(p.child.id()) {
                // SAFETY: kill(2) on the pid of a child not reaped yet (so not reused).
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
        }
    }

    /// Kills the process of `role` and `epoch` if it is still running; returns its pid
    /// then.
    fn kill_running(&mut self, role: Role, epoch: u32) -> Option<u32> {
        let p = self
            .list
            .iter_mut()
            .find(|p| p.role == role && p.epoch == epoch)?;
        if p.child.try_wait().ok().flatten().is_some() {
            return None;
        }
        p.child.kill().ok().map(|()| p.child.id())
    }

    /// Whether a process of `role` is being stopped.
    fn retiring(&self, role: Role) -> bool {
        self.list
            .iter()
            .any(|p| p.role == role && p.retire_by.is_some())
    }

    /// Kills retiring processes that outlived their grace period.
    fn kill_overdue(&mut self) {
        let now = Instant::now();
        for p in &mut self.list {
            if p.retire_by.is_some_and(|by| now > by) {
                let _ = p.child.kill();
            }
        }
    }

    /// A child that has exited (reaped and forgotten), with its status.
    fn take_exited(&mut self) -> Option<(Proc, std::process::ExitStatus)> {
        let index = self
            .list
            .iter_mut()
            .position(|p| p.child.try_wait().ok().flatten().is_some())?;
        let mut proc = self.list.remove(index);
        let status = proc.child.try_wait().ok().flatten()?;
        Some((proc, status))
    }

    /// Waits up to `timeout` for every child to exit, then kills the rest; reaps all.
    /// Returns each role's exit status and whether it had to be killed.
    fn shut_down(&mut self, timeout: Duration) -> Vec<(Role, u32, String, bool)> {
        let deadline = Instant::now() + timeout;
        let mut ended = Vec::new();
        for p in &mut self.list {
            let child = &mut p.child;
            while child.try_wait().ok().flatten().is_none() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(5));
            }
            let killed = child.try_wait().ok().flatten().is_none();
            if killed {
                let _ = child.kill();
            }
            let status = child
                .wait()
                .map_or_else(|e| e.to_string(), |s| s.to_string());
            ended.push((p.role, p.epoch, status, killed));
        }
        self.list.clear();
        ended
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        let _ = self.shut_down(Duration::ZERO);
    }
}

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
    /// Live requests of `scmpc swap`, and the answers.
    swap_requests: Receiver<SwapRequest>,
    swap_replies: Sender<SwapReply>,
    /// Which producer of each role is taken, announced with every control message.
    schedule: std::cell::Cell<EpochSchedule>,
    /// The node of the ports above; declared last, so it is dropped after them.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Session {
    fn open(prefix: &str) -> Result<Session, ipc::IpcError> {
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
            swap_requests: open_topic(&node, ipc::SWAP)?.receiver()?,
            swap_replies: open_topic(&node, ipc::SWAP_REPLY)?.sender(0)?,
            schedule: std::cell::Cell::new(EpochSchedule::default()),
            _node: node,
        };
        for input in session.inputs() {
            input.follow(EpochSchedule::default());
        }
        Ok(session)
    }

    fn command(
        &self,
        command: ControlCommand,
        tick: u64,
        start_ns: u64,
    ) -> Result<(), ipc::IpcError> {
        self.control.send(Control {
            header: Header {
                tick,
                ..Header::default()
            },
            command: command as u32,
            start_ns,
            epochs: self.schedule.get(),
            ..Control::default()
        })
    }

    /// The orchestrator's inputs, for housekeeping.
    fn inputs(&self) -> [&dyn Input; 6] {
        [
            &self.truth,
            &self.measurement,
            &self.estimate,
            &self.plan,
            &self.actuation,
            &self.deadline,
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

    /// The orchestrator's input carrying the output of `role`: how it sees a replacement
    /// warm up.
    fn output_of(&self, role: Role) -> &dyn Input {
        match role {
            Role::Plant => &self.truth,
            Role::Estimator => &self.estimate,
            Role::Mpc => &self.plan,
            Role::Dfl => &self.actuation,
        }
    }

    /// Samples the orchestrator itself refused, by rejection code, since the last call.
    fn take_rejections(&self) -> [u64; 4] {
        let mut total = [0; 4];
        for input in self.inputs() {
            for (t, n) in total.iter_mut().zip(input.take_rejections()) {
                *t += n;
            }
        }
        total
    }
}

/// A replacement being swapped in (DESIGN.md section 5).
struct Swap {
    role: Role,
    /// Epoch of the replacement, and of the process it replaces.
    epoch: u32,
    replaces: u32,
    pid: u32,
    /// The command as shown in events.
    command: String,
    started: Instant,
    /// The `scmpc swap` request to answer, if it came from one.
    request: Option<u64>,
    /// First and newest tick the replacement has published while warming up.
    heard: Option<(u64, u64)>,
    /// First tick taken from the replacement, once scheduled.
    switch_tick: Option<u64>,
}

/// A swap waiting for its time, or for its role to be free of another swap.
struct PendingSwap {
    time_s: f64,
    role: Role,
    command: Vec<String>,
    /// The `scmpc swap` request to answer.
    request: Option<u64>,
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
    newest_truth: Option<u64>,
    stop: &'a AtomicBool,
    start_ns: u64,
    record_gaps: u64,
    restarts: u32,
    /// Samples refused by any consumer, by reason.
    rejected: BTreeMap<String, u64>,
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
}

impl Driver<'_> {
    /// Waits for input (at most [`POLL`]) and files everything received by tick.
    fn pump(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<()> {
        ipc::wait(waitset, POLL)?;
        // Ticks already recorded come again only as replays: skipped.
        let cursor = self.cursor;
        let slots = &mut self.slots;
        let newest = &mut self.newest_truth;
        self.session.truth.drain(|m, _| {
            *newest = (*newest).max(Some(m.header.tick));
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.truth = Some(m);
            }
        })?;
        self.session.measurement.drain(|m, _| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.measurement = Some(m);
            }
        })?;
        self.session.estimate.drain(|m, _| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.estimate = Some(m);
            }
        })?;
        self.session.actuation.drain(|m, l| {
            if let Some(s) = slot(slots, cursor, m.header.tick) {
                s.actuation = Some((m, l));
            }
        })?;
        let plans = &mut self.plans;
        self.session.plan.drain(|p, _| {
            plans.insert(p.sample, p);
        })?;
        let mut restarted_ready = Vec::new();
        let mut rejected = Vec::new();
        self.session.status.drain(|s, _| {
            if s.event == StatusEvent::Ready as u32 {
                restarted_ready.extend(Role::from_code(s.role));
            } else if s.event == StatusEvent::Rejected as u32 {
                rejected.push((
                    Role::from_code(s.role).map_or("unknown", Role::as_str),
                    s.detail,
                    s.count,
                ));
            }
        })?;
        for (code, count) in self.session.take_rejections().into_iter().enumerate() {
            if count > 0 {
                rejected.push(("orchestrator", code as u32, count));
            }
        }
        for (consumer, code, count) in rejected {
            let reason = Rejection::ALL
                .get(code as usize)
                .map_or("unknown", |r| r.as_str());
            *self.rejected.entry(reason.to_string()).or_default() += count;
            self.recorder.event(
                "rejected",
                serde_json::json!({ "consumer": consumer, "reason": reason, "count": count }),
            )?;
        }
        for role in restarted_ready {
            // A process joined the running loop: tell it the clock and the schedule, and
            // have every producer repeat its newest sample for it; watch its node.
            self.recorder
                .event("ready", serde_json::json!({ "role": role.as_str() }))?;
            self.last_node_listing = None;
            match self.mode {
                RunMode::Realtime => {
                    self.session
                        .command(ControlCommand::Start, 0, self.start_ns)?
                }
                RunMode::Lockstep => self.session.command(ControlCommand::Epochs, 0, 0)?,
            }
            self.session.command(ControlCommand::Replay, 0, 0)?;
        }
        let verdicts = &mut self.verdicts;
        self.session.deadline.drain(|v, _| {
            verdicts.insert(v.sample, v);
        })?;
        Ok(())
    }

    /// Ends the run on Ctrl-C; handles a process that exited: a retired one is
    /// forgotten, a failed replacement cancels its swap, and a dead active process is
    /// cleaned up after and then replaced by its warming replacement if there is one, else
    /// restarted per the scenario's supervision policy, else the run ends as aborted.
    fn check(&mut self) -> anyhow::Result<Option<Outcome>> {
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        self.children.kill_overdue();
        if self.last_node_scan.elapsed() >= NODE_SCAN {
            self.last_node_scan = Instant::now();
            self.watch_nodes()?;
        }
        let Some((proc, status)) = self.children.take_exited() else {
            return Ok(None);
        };
        let role = proc.role;
        let cleaned = self.clean_dead_nodes(Some((role, proc.epoch)))?;
        if proc.retire_by.is_some() {
            self.recorder.event(
                "retired",
                serde_json::json!({ "role": role.as_str(), "epoch": proc.epoch, "status": status.to_string() }),
            )?;
            return Ok(None);
        }
        if let Some(i) = self
            .swaps
            .iter()
            .position(|s| s.role == role && s.epoch == proc.epoch)
        {
            let swap = self.swaps.remove(i);
            self.fail_swap(swap, &format!("the replacement exited ({status})"))?;
            return Ok(None);
        }
        // A terminal's Ctrl-C reaches the whole process group: the children may see it a
        // moment before the orchestrator's handler runs.
        std::thread::sleep(Duration::from_millis(20));
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        self.recorder.event(
            "crashed",
            serde_json::json!({ "role": role.as_str(), "epoch": proc.epoch, "status": status.to_string(), "nodes_cleaned": cleaned }),
        )?;
        if let Some(i) = self.swaps.iter().position(|s| s.role == role) {
            // Its replacement is already running: it takes over at once.
            let swap = self.swaps.remove(i);
            self.complete_swap(swap, "promoted after the crash")?;
            return Ok(None);
        }
        let policy = &self.scenario.supervision;
        let restartable = role != Role::Plant
            && policy.restart == RestartPolicy::Always
            && self.restarts < policy.max_restarts;
        if !restartable {
            return Ok(Some(Outcome::Aborted));
        }
        self.restarts += 1;
        let epoch = self.take_epoch();
        self.session.reschedule(|s| s.activate(role, epoch))?;
        let pid = self.children.spawn_role(role, epoch, &[])?;
        self.recorder.event(
            "restarted",
            serde_json::json!({ "role": role.as_str(), "pid": pid, "epoch": epoch }),
        )?;
        Ok(None)
    }

    /// Looks for dead nodes: a full iceoryx2 node listing (about 1 ms of CPU) every
    /// [`NODE_LISTING`], and in between only whether the processes of the nodes listed
    /// are still alive (microseconds), so the scan does not disturb the control loop.
    fn watch_nodes(&mut self) -> anyhow::Result<()> {
        let someone_died = self.node_pids.iter().any(|pid| !ipc::process_alive(*pid));
        if someone_died
            || self
                .last_node_listing
                .is_none_or(|t| t.elapsed() >= NODE_LISTING)
        {
            self.clean_dead_nodes(None)?;
            self.node_pids = ipc::node_pids(&self.children.prefix).unwrap_or_default();
            self.last_node_listing = Some(Instant::now());
        }
        Ok(())
    }

    /// iceoryx2's dead-node detection: removes what dead nodes of the run left. A role
    /// process that died while the process the orchestrator started for it lives on (a
    /// wrapper script, say) is recorded as `dead_node`, and that process is killed, so its
    /// exit is handled as a crash. Nothing is recorded for the node of `exited` (the child
    /// whose exit is being handled) nor for one whose child has exited already (its exit
    /// comes next). Returns how many nodes were cleaned.
    fn clean_dead_nodes(&mut self, exited: Option<(Role, u32)>) -> anyhow::Result<usize> {
        let names = ipc::cleanup_dead_nodes(&self.children.prefix).unwrap_or_default();
        for name in &names {
            let Some((role, epoch)) = ipc::role_of_node(name) else {
                continue;
            };
            if exited == Some((role, epoch)) {
                continue;
            }
            let ours = self.children.pid(role, epoch).is_some();
            let killed = self.children.kill_running(role, epoch);
            if killed.is_some() || !ours {
                self.recorder.event(
                    "dead_node",
                    serde_json::json!({ "node": name, "role": role.as_str(), "epoch": epoch, "child_killed": killed }),
                )?;
            }
        }
        Ok(names.len())
    }

    fn take_epoch(&mut self) -> u32 {
        self.next_epoch += 1;
        self.next_epoch
    }

    /// Current tick: the next to record in lockstep, the wall clock's in real time.
    fn now_tick(&self) -> u64 {
        match self.mode {
            RunMode::Lockstep => self.cursor,
            RunMode::Realtime => {
                let dt_ns = self.scenario.timing.dt_s() * 1e9;
                (monotonic_ns().saturating_sub(self.start_ns) as f64 / dt_ns) as u64
            }
        }
    }

    /// Starts swaps that are due, takes live requests, and moves every swap on: a warm
    /// replacement is scheduled to take over at a sample boundary [`SWITCH_LEAD_SAMPLES`]
    /// ahead; once that tick is recorded the old process is retired.
    fn supervise(&mut self) -> anyhow::Result<()> {
        let time_s = self.cursor as f64 * self.scenario.timing.dt_s();
        let mut requests = Vec::new();
        // Straight from shared memory: nothing waits on this listener.
        self.session.swap_requests.take(|r, _| requests.push(r))?;
        for r in requests {
            match Role::from_code(r.role) {
                Some(Role::Plant) => {
                    self.reply(r.request_id, None, "the plant cannot be swapped")?
                }
                Some(role) => self.scheduled.push(PendingSwap {
                    time_s: 0.0,
                    role,
                    command: r.command(),
                    request: Some(r.request_id),
                }),
                None => self.reply(r.request_id, None, &format!("no role with code {}", r.role))?,
            }
        }
        // One swap per role at a time: the next starts once the process replaced has exited.
        while let Some(i) = self.scheduled.iter().position(|p| {
            p.time_s <= time_s
                && self.swaps.iter().all(|s| s.role != p.role)
                && !self.children.retiring(p.role)
        }) {
            let p = self.scheduled.remove(i);
            self.begin_swap(p.role, p.command, p.request)?;
        }
        let inner_steps = self.scenario.timing.inner_steps as u64;
        let now_tick = self.now_tick();
        let mut i = 0;
        while i < self.swaps.len() {
            let swap = &mut self.swaps[i];
            let role = swap.role;
            match swap.switch_tick {
                None => {
                    if let Some(t) = self.session.output_of(role).take_standby_newest() {
                        let (first, _) = swap.heard.unwrap_or((t, t));
                        swap.heard = Some((first, t));
                    }
                    let warm = swap.heard.is_some_and(|(first, newest)| {
                        newest >= first + SWAP_WARMUP_SAMPLES * inner_steps
                    });
                    if warm {
                        let newest = swap.heard.map_or(0, |h| h.1);
                        let lead = now_tick.max(newest) + SWITCH_LEAD_SAMPLES * inner_steps;
                        let tick = lead.div_ceil(inner_steps) * inner_steps;
                        swap.switch_tick = Some(tick);
                        let epoch = swap.epoch;
                        self.session.reschedule(|s| s.schedule_switch(role, tick))?;
                        self.recorder.event(
                            "swap_scheduled",
                            serde_json::json!({ "role": role.as_str(), "epoch": epoch, "switch_tick": tick }),
                        )?;
                    } else if swap.started.elapsed() > SWAP_TIMEOUT {
                        let swap = self.swaps.remove(i);
                        self.fail_swap(
                            swap,
                            &format!(
                                "the replacement published nothing usable within {SWAP_TIMEOUT:?}"
                            ),
                        )?;
                        continue;
                    }
                }
                Some(tick) if self.cursor > tick => {
                    let swap = self.swaps.remove(i);
                    self.complete_swap(swap, "switched")?;
                    continue;
                }
                Some(_) => {}
            }
            i += 1;
        }
        Ok(())
    }

    /// Starts `command` (empty: the built-in process) as the replacement of `role`.
    fn begin_swap(
        &mut self,
        role: Role,
        command: Vec<String>,
        request: Option<u64>,
    ) -> anyhow::Result<()> {
        let epoch = self.take_epoch();
        let replaces = self.session.schedule.get().current(role);
        self.session.reschedule(|s| s.announce(role, epoch))?;
        let _ = self.session.output_of(role).take_standby_newest();
        let shown = if command.is_empty() {
            format!("scmpc {}", role.as_str())
        } else {
            command.join(" ")
        };
        match self.children.spawn_role(role, epoch, &command) {
            Ok(pid) => {
                self.recorder.event(
                    "swap_started",
                    serde_json::json!({ "role": role.as_str(), "epoch": epoch, "replaces": replaces, "pid": pid, "command": shown }),
                )?;
                self.swaps.push(Swap {
                    role,
                    epoch,
                    replaces,
                    pid,
                    command: shown,
                    started: Instant::now(),
                    request,
                    heard: None,
                    switch_tick: None,
                });
                Ok(())
            }
            Err(e) => {
                self.session.reschedule(|s| s.unschedule(role))?;
                self.recorder.event(
                    "swap_failed",
                    serde_json::json!({ "role": role.as_str(), "epoch": epoch, "command": shown, "reason": format!("{e:#}") }),
                )?;
                match request {
                    Some(id) => self.reply(id, None, &format!("{e:#}")),
                    None => Ok(()),
                }
            }
        }
    }

    /// The replacement has taken over (at its switch tick, or at once when the process it
    /// replaces died): the old process is retired.
    fn complete_swap(&mut self, swap: Swap, how: &str) -> anyhow::Result<()> {
        let role = swap.role;
        let old_pid = self.children.pid(role, swap.replaces);
        if old_pid.is_some() {
            self.children.retire(role, swap.replaces, STOP_TIMEOUT);
        } else {
            self.session.reschedule(|s| s.activate(role, swap.epoch))?;
            if self.mode == RunMode::Lockstep {
                // The loop may be waiting for a sample only the new producer can now give.
                self.session.command(ControlCommand::Replay, 0, 0)?;
            }
        }
        self.swaps_done += 1;
        let tick = swap.switch_tick;
        self.recorder.event(
            "swapped",
            serde_json::json!({
                "role": role.as_str(), "from_epoch": swap.replaces, "to_epoch": swap.epoch,
                "old_pid": old_pid, "new_pid": swap.pid, "switch_tick": tick, "how": how,
                "warmup_s": swap.started.elapsed().as_secs_f64(),
            }),
        )?;
        match swap.request {
            Some(id) => self.reply(id, Some(&swap), how),
            None => Ok(()),
        }
    }

    /// Drops a replacement: the old process stays the producer; the replacement is
    /// retired if it still runs.
    fn fail_swap(&mut self, swap: Swap, reason: &str) -> anyhow::Result<()> {
        let role = swap.role;
        self.session.reschedule(|s| s.unschedule(role))?;
        self.children.retire(role, swap.epoch, STOP_TIMEOUT);
        if self.mode == RunMode::Lockstep && swap.switch_tick.is_some() {
            // Samples of the old producer past the switch were skipped: have them again.
            self.session.command(ControlCommand::Replay, 0, 0)?;
        }
        self.recorder.event(
            "swap_failed",
            serde_json::json!({ "role": role.as_str(), "epoch": swap.epoch, "command": swap.command, "reason": reason }),
        )?;
        match swap.request {
            Some(id) => self.reply(id, None, reason),
            None => Ok(()),
        }
    }

    /// Answers a `scmpc swap` request: done with `swap`, or failed.
    fn reply(&self, request_id: u64, swap: Option<&Swap>, message: &str) -> anyhow::Result<()> {
        let reply = SwapReply {
            request_id,
            done: u32::from(swap.is_some()),
            epoch: swap.map_or(0, |s| s.epoch),
            switch_tick: swap.and_then(|s| s.switch_tick).unwrap_or(0),
            ..SwapReply::default()
        }
        .with_message(message);
        Ok(self.session.swap_replies.send(reply)?)
    }

    /// Records a whole tick; returns an outcome that ends the run.
    fn record(&mut self, tick: u64, slot: TickSlot) -> anyhow::Result<Option<Outcome>> {
        let (Some(truth), Some(measurement), Some((act, own_latency))) =
            (slot.truth, slot.measurement, slot.actuation)
        else {
            return Ok(None);
        };
        let inner_steps = self.scenario.timing.inner_steps as u64;
        let l = &mut self.latencies;
        l.hop(
            "control_to_plant",
            u64::from(measurement.header.input_latency_ns),
        );
        // A tick the DFL commanded without an estimate (estimator silent, DFL braking) is
        // recorded with an estimate of NaN.
        self.ticks_without_estimate += u64::from(slot.estimate.is_none());
        let estimate = slot.estimate.unwrap_or(Estimate {
            state: [f64::NAN; 4],
            ..Estimate::default()
        });
        if slot.estimate.is_some() {
            l.hop(
                "measurement_to_estimator",
                u64::from(estimate.header.input_latency_ns),
            );
            l.hop("estimate_to_dfl", u64::from(act.header.input_latency_ns));
        }
        if self.mode == RunMode::Lockstep {
            // In real time the orchestrator drains its buffers periodically: not a hop.
            l.hop("actuation_to_orchestrator", own_latency);
        }
        if !tick.is_multiple_of(inner_steps) && slot.estimate.is_some() {
            l.sensor_to_actuator(
                act.header
                    .publish_ns
                    .saturating_sub(measurement.header.publish_ns),
            );
        }
        Ok(self.recorder.tick(&truth, &estimate, &act)?)
    }

    /// Records every plan received, then every deadline verdict (the DFL judges sample k
    /// at the start of sample k + 1, after plan(k) was published).
    fn record_plans(&mut self) -> anyhow::Result<()> {
        while let Some((sample, plan)) = self.plans.pop_first() {
            // A replay repeats a plan already recorded.
            if self.last_plan.is_some_and(|last| sample <= last) {
                continue;
            }
            self.last_plan = Some(sample);
            self.latencies
                .hop("estimate_to_mpc", u64::from(plan.header.input_latency_ns));
            self.recorder.plan(&plan);
        }
        while let Some((_, v)) = self.verdicts.pop_first() {
            self.recorder.verdict(&v)?;
        }
        Ok(())
    }

    fn lockstep(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<Outcome> {
        let ticks = self.scenario.tick_count();
        let inner_steps = self.scenario.timing.inner_steps as u64;
        for tick in 0..=ticks {
            self.session.command(ControlCommand::Grant, tick, 0)?;
            let boundary = tick.is_multiple_of(inner_steps) && tick < ticks;
            let mut last_progress = Instant::now();
            loop {
                let done = if tick == ticks {
                    self.slots.get(&tick).is_some_and(|s| s.truth.is_some())
                } else {
                    self.slots.get(&tick).is_some_and(TickSlot::complete)
                        && (!boundary || self.plans.contains_key(&(tick / inner_steps)))
                };
                if done {
                    break;
                }
                if let Some(outcome) = self.check()? {
                    return Ok(outcome);
                }
                if last_progress.elapsed() > TICK_TIMEOUT {
                    bail!("tick {tick} made no progress for {TICK_TIMEOUT:?}: a process hung");
                }
                let before = self.slots.len() + self.plans.len();
                self.pump(waitset)?;
                if self.slots.len() + self.plans.len() != before {
                    last_progress = Instant::now();
                }
            }
            let slot = self.slots.remove(&tick).unwrap_or_default();
            if tick == ticks {
                let end = slot.truth.and_then(|t| self.recorder.final_pose(&t));
                return Ok(end.unwrap_or_else(|| self.recorder.monitor.final_outcome()));
            }
            self.record_plans()?;
            if let Some(outcome) = self.record(tick, slot)? {
                return Ok(outcome);
            }
            self.cursor = tick + 1;
            self.supervise()?;
        }
        Ok(self.recorder.monitor.final_outcome())
    }

    fn realtime(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<Outcome> {
        let ticks = self.scenario.tick_count();
        let inner_steps = self.scenario.timing.inner_steps as u64;
        self.start_ns = monotonic_ns() + START_LEAD.as_nanos() as u64;
        self.session
            .command(ControlCommand::Start, 0, self.start_ns)?;
        let end_ns = self.start_ns + (self.scenario.duration_s * 1e9) as u64;
        let give_up_ns = end_ns + 5_000_000_000;
        let mut next = 0u64;
        loop {
            if let Some(outcome) = self.check()? {
                return Ok(outcome);
            }
            if monotonic_ns() > give_up_ns {
                bail!("the run did not finish within 5 s after its end: a process hung");
            }
            self.pump(waitset)?;
            self.record_plans()?;
            self.supervise()?;
            while next <= ticks {
                let complete = self.slots.get(&next).is_some_and(|s| {
                    if next == ticks {
                        s.truth.is_some()
                    } else {
                        s.complete()
                    }
                });
                let overdue = self
                    .newest_truth
                    .is_some_and(|t| t >= next + 2 * inner_steps);
                if !complete && !overdue {
                    break;
                }
                let slot = self.slots.remove(&next).unwrap_or_default();
                if next == ticks {
                    let end = slot.truth.and_then(|t| self.recorder.final_pose(&t));
                    return Ok(end.unwrap_or_else(|| self.recorder.monitor.final_outcome()));
                }
                let commanded =
                    slot.truth.is_some() && slot.measurement.is_some() && slot.actuation.is_some();
                if !complete && !commanded {
                    self.record_gaps += 1;
                    self.recorder
                        .event("record_gap", serde_json::json!({ "tick": next }))?;
                } else if let Some(outcome) = self.record(next, slot)? {
                    return Ok(outcome);
                }
                next += 1;
                self.cursor = next;
            }
        }
    }
}

/// `run.json` of a run directory: how tools such as `scmpc swap` reach the running run.
#[derive(Debug, serde::Serialize, serde::Deserialize)]
pub struct RunInfo {
    pub iceoryx2_prefix: String,
    pub orchestrator_pid: u32,
    pub mode: String,
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
/// writes `out`. The scenario must be valid. Whatever happens, every process is stopped
/// and the run's iceoryx2 resources are removed before this returns.
pub fn run(
    scenario: &Scenario,
    out: &Path,
    mode: RunMode,
    prefix: &str,
    stop: &AtomicBool,
) -> anyhow::Result<Summary> {
    let started = Instant::now();
    for stale in ipc::stale_run_prefixes() {
        match ipc::remove_run_resources(&stale) {
            Ok(()) => tracing::info!("removed the iceoryx2 resources of dead run `{stale}`"),
            Err(e) => tracing::warn!("cannot remove the resources of dead run `{stale}`: {e}"),
        }
    }
    let mut recorder =
        Recorder::create(out, scenario).with_context(|| format!("creating {}", out.display()))?;
    RunInfo {
        iceoryx2_prefix: prefix.to_string(),
        orchestrator_pid: std::process::id(),
        mode: mode_name(mode).to_string(),
    }
    .write(out)?;
    let result = drive(scenario, out, mode, prefix, stop, &mut recorder);
    if let Err(e) = ipc::remove_run_resources(prefix) {
        tracing::warn!("cleaning up the run's iceoryx2 resources: {e}");
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
    let session = Session::open(prefix)?;
    let mut children = Children::spawn(&out.join("scenario.toml"), prefix, mode)?;
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
    }
    let outcome = wait_until_ready(&session, &waitset, &mut children, stop).and_then(|()| {
        recorder.event("ready", serde_json::json!({ "iceoryx2_prefix": prefix }))?;
        let mut driver = Driver {
            scenario,
            mode,
            session: &session,
            children: &mut children,
            recorder: &mut *recorder,
            latencies: Latencies::default(),
            slots: BTreeMap::new(),
            plans: BTreeMap::new(),
            verdicts: BTreeMap::new(),
            newest_truth: None,
            stop,
            start_ns: 0,
            record_gaps: 0,
            restarts: 0,
            rejected: BTreeMap::new(),
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
        };
        let outcome = match mode {
            RunMode::Lockstep => driver.lockstep(&waitset),
            RunMode::Realtime => driver.realtime(&waitset),
        };
        let outcome = outcome.and_then(|o| driver.record_plans().map(|()| o));
        for swap in std::mem::take(&mut driver.swaps) {
            driver.fail_swap(swap, "the run ended before the switch")?;
        }
        for pending in std::mem::take(&mut driver.scheduled) {
            if let Some(id) = pending.request {
                driver.reply(id, None, "the run ended before the swap could start")?;
            }
        }
        driver.latencies.report(&mut report);
        report.record_gaps = driver.record_gaps;
        report.ticks_without_estimate = driver.ticks_without_estimate;
        report.restarts = driver.restarts;
        report.swaps = driver.swaps_done;
        report.rejected_samples = std::mem::take(&mut driver.rejected);
        outcome
    });
    // Peak resident memory of every process still running, then stop them all whatever
    // happened, then release the orchestrator's own ports.
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

/// Peak resident set size of process `pid` (`VmHWM`), KiB.
fn peak_rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// The scenario's `[[swap]]` entries, earliest first (validated: the roles are swappable).
fn scheduled_swaps(scenario: &Scenario) -> Vec<PendingSwap> {
    let mut swaps: Vec<_> = scenario
        .swap
        .iter()
        .filter_map(|s| {
            Some(PendingSwap {
                time_s: s.time_s,
                role: s.swappable_role()?,
                command: s.command.clone(),
                request: None,
            })
        })
        .collect();
    swaps.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    swaps
}

/// Waits until every role has reported ready.
fn wait_until_ready(
    session: &Session,
    waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    children: &mut Children,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    let deadline = Instant::now() + READY_TIMEOUT;
    let mut ready = [false; 4];
    while !ready.iter().all(|r| *r) {
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
            let missing: Vec<&str> = Role::ALL
                .iter()
                .filter(|r| !ready[**r as usize])
                .map(|r| r.as_str())
                .collect();
            return Err(anyhow!(
                "no ready report within {READY_TIMEOUT:?} from: {}",
                missing.join(", ")
            ));
        }
        ipc::wait(waitset, POLL)?;
        session.status.drain(|s, _| {
            if s.event == StatusEvent::Ready as u32
                && let Some(role) = Role::from_code(s.role)
            {
                ready[role as usize] = true;
            }
        })?;
    }
    Ok(())
}
