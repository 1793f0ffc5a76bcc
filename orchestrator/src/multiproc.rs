//! `scmpc run` over iceoryx2: the four roles as separate processes, launched, clocked and
//! recorded by the orchestrator.
//!
//! Lockstep: the orchestrator grants tick `j` to the plant, and the data flow carries it
//! through estimator, MPC and DFL; the orchestrator records tick `j` (it subscribes to
//! every topic) before it grants `j + 1`, so the recorder is part of the handshake and
//! loses nothing. Real time: the orchestrator publishes the monotonic time of tick 0 and
//! records ticks as they complete, counting every tick it never receives whole.

use crate::inprocess::tick_count;
use crate::monitor::Outcome;
use crate::record::{Latencies, ProcessReport, Recorder, Summary};
use anyhow::{Context, anyhow, bail};
use protocol::clock::monotonic_ns;
use protocol::ipc::{self, Input, Receiver, RunMode, Sender, open_topic};
use protocol::{
    Actuation, Control, ControlCommand, DeadlineVerdict, Estimate, GroundTruth, Header,
    Measurement, Plan, Rejection, RestartPolicy, Role, Scenario, Status, StatusEvent,
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

/// The run's processes; killed and reaped on drop whatever happened.
struct Children {
    exe: std::path::PathBuf,
    scenario_file: std::path::PathBuf,
    prefix: String,
    mode: &'static str,
    list: Vec<(Role, Child)>,
}

impl Children {
    fn spawn(scenario_file: &Path, prefix: &str, mode: RunMode) -> anyhow::Result<Children> {
        let mut children = Children {
            exe: std::env::current_exe().context("locating the scmpc executable")?,
            scenario_file: scenario_file.to_path_buf(),
            prefix: prefix.to_string(),
            mode: match mode {
                RunMode::Lockstep => "lockstep",
                RunMode::Realtime => "realtime",
            },
            list: Vec::new(),
        };
        for role in Role::ALL {
            children.spawn_role(role, 0)?;
        }
        Ok(children)
    }

    /// Starts the process of `role` with producer epoch `epoch`; returns its pid.
    fn spawn_role(&mut self, role: Role, epoch: u32) -> anyhow::Result<u32> {
        let child = Command::new(&self.exe)
            .arg(role.as_str())
            .arg("--scenario")
            .arg(&self.scenario_file)
            .args([
                "--prefix",
                &self.prefix,
                "--mode",
                self.mode,
                "--epoch",
                &epoch.to_string(),
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| format!("starting the {} process", role.as_str()))?;
        let pid = child.id();
        self.list.push((role, child));
        Ok(pid)
    }

    /// A child that has exited (reaped and forgotten), with its status.
    fn take_exited(&mut self) -> Option<(Role, std::process::ExitStatus)> {
        let index = self
            .list
            .iter_mut()
            .position(|(_, child)| child.try_wait().ok().flatten().is_some())?;
        let (role, mut child) = self.list.remove(index);
        child.try_wait().ok().flatten().map(|status| (role, status))
    }

    /// Waits up to `timeout` for every child to exit, then kills the rest; reaps all.
    /// Returns each role's exit status and whether it had to be killed.
    fn shut_down(&mut self, timeout: Duration) -> Vec<(Role, String, bool)> {
        let deadline = Instant::now() + timeout;
        let mut ended = Vec::new();
        for (role, child) in &mut self.list {
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
            ended.push((*role, status, killed));
        }
        ended
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        let _ = self.shut_down(Duration::ZERO);
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
    /// Active producer epoch of each role, announced with every control message.
    epochs: std::cell::Cell<[u32; 4]>,
    /// The node of the ports above; declared last, so it is dropped after them.
    _node: iceoryx2::prelude::Node<iceoryx2::prelude::ipc::Service>,
}

impl Session {
    fn open(prefix: &str) -> Result<Session, ipc::IpcError> {
        let node = ipc::create_node(prefix, "orchestrator", false)?;
        Ok(Session {
            control: open_topic(&node, ipc::CONTROL)?.sender(0)?,
            status: open_topic(&node, ipc::STATUS)?.receiver()?,
            truth: open_topic(&node, ipc::TRUTH)?.receiver_from(Role::Plant)?,
            measurement: open_topic(&node, ipc::MEASUREMENT)?.receiver_from(Role::Plant)?,
            estimate: open_topic(&node, ipc::ESTIMATE)?.receiver_from(Role::Estimator)?,
            plan: open_topic(&node, ipc::PLAN)?.receiver_from(Role::Mpc)?,
            actuation: open_topic(&node, ipc::ACTUATION)?.receiver_from(Role::Dfl)?,
            deadline: open_topic(&node, ipc::DEADLINE)?.receiver_from(Role::Dfl)?,
            epochs: std::cell::Cell::new([0; 4]),
            _node: node,
        })
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
            epochs: self.epochs.get(),
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

    /// Makes `epoch` the active one of `role`, for the orchestrator and every process.
    fn activate(&self, role: Role, epoch: u32) -> Result<(), ipc::IpcError> {
        let mut epochs = self.epochs.get();
        epochs[role as usize] = epoch;
        self.epochs.set(epochs);
        for input in self.inputs() {
            if input.producer() == Some(role) {
                input.expect_epoch(epoch);
            }
        }
        self.command(ControlCommand::Epochs, 0, 0)
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
}

impl Driver<'_> {
    /// Waits for input (at most [`POLL`]) and files everything received by tick.
    fn pump(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<()> {
        ipc::wait(waitset, POLL)?;
        let slots = &mut self.slots;
        let newest = &mut self.newest_truth;
        self.session.truth.drain(|m, _| {
            *newest = (*newest).max(Some(m.header.tick));
            slots.entry(m.header.tick).or_default().truth = Some(m);
        })?;
        self.session
            .measurement
            .drain(|m, _| slots.entry(m.header.tick).or_default().measurement = Some(m))?;
        self.session
            .estimate
            .drain(|m, _| slots.entry(m.header.tick).or_default().estimate = Some(m))?;
        self.session
            .actuation
            .drain(|m, l| slots.entry(m.header.tick).or_default().actuation = Some((m, l)))?;
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
            // A restarted process missed the start: tell everyone again (same tick 0).
            self.recorder
                .event("ready", serde_json::json!({ "role": role.as_str() }))?;
            if self.mode == RunMode::Realtime {
                self.session
                    .command(ControlCommand::Start, 0, self.start_ns)?;
            }
        }
        let verdicts = &mut self.verdicts;
        self.session.deadline.drain(|v, _| {
            verdicts.insert(v.sample, v);
        })?;
        Ok(())
    }

    /// Ends the run on Ctrl-C; on a dead process, cleans what it left and restarts it per
    /// the scenario's supervision policy, or ends the run as aborted.
    fn check(&mut self) -> anyhow::Result<Option<Outcome>> {
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        let Some((role, status)) = self.children.take_exited() else {
            return Ok(None);
        };
        // A terminal's Ctrl-C reaches the whole process group: the children may see it a
        // moment before the orchestrator's handler runs.
        std::thread::sleep(Duration::from_millis(20));
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        let cleaned = ipc::cleanup_dead_nodes(&self.children.prefix).unwrap_or(0);
        let role_name = role.as_str();
        self.recorder.event(
            "crashed",
            serde_json::json!({ "role": role_name, "status": status.to_string(), "nodes_cleaned": cleaned }),
        )?;
        let policy = &self.scenario.supervision;
        let restartable = role != Role::Plant
            && self.mode == RunMode::Realtime
            && policy.restart == RestartPolicy::Always
            && self.restarts < policy.max_restarts;
        if !restartable {
            return Ok(Some(Outcome::Aborted));
        }
        self.restarts += 1;
        self.session.activate(role, self.restarts)?;
        let pid = self.children.spawn_role(role, self.restarts)?;
        self.recorder.event(
            "restarted",
            serde_json::json!({ "role": role_name, "pid": pid, "epoch": self.restarts }),
        )?;
        Ok(None)
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
        while let Some((_, plan)) = self.plans.pop_first() {
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
        let ticks = tick_count(self.scenario);
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
        }
        Ok(self.recorder.monitor.final_outcome())
    }

    fn realtime(
        &mut self,
        waitset: &iceoryx2::prelude::WaitSet<iceoryx2::prelude::ipc::Service>,
    ) -> anyhow::Result<Outcome> {
        let ticks = tick_count(self.scenario);
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
            }
        }
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
    let result = drive(scenario, out, mode, prefix, stop, &mut recorder);
    if let Err(e) = ipc::remove_run_resources(prefix) {
        tracing::warn!("cleaning up the run's iceoryx2 resources: {e}");
    }
    let (outcome, mut report) = result?;
    report.leftover_files = ipc::leftover_files(prefix)
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    let mode_name = match mode {
        RunMode::Lockstep => "lockstep",
        RunMode::Realtime => "realtime",
    };
    Ok(recorder.finish(
        scenario,
        mode_name,
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
    for (role, child) in &children.list {
        report.pids.insert(role.as_str().into(), child.id());
        recorder.event(
            "spawned",
            serde_json::json!({ "role": role.as_str(), "pid": child.id() }),
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
        };
        let outcome = match mode {
            RunMode::Lockstep => driver.lockstep(&waitset),
            RunMode::Realtime => driver.realtime(&waitset),
        };
        let outcome = outcome.and_then(|o| driver.record_plans().map(|()| o));
        driver.latencies.report(&mut report);
        report.record_gaps = driver.record_gaps;
        report.rejected_samples = std::mem::take(&mut driver.rejected);
        outcome
    });
    // Stop every process whatever happened, then release the orchestrator's own ports.
    let _ = session.command(ControlCommand::Stop, 0, 0);
    for (role, status, killed) in children.shut_down(STOP_TIMEOUT) {
        recorder.event(
            "exited",
            serde_json::json!({ "role": role.as_str(), "status": status, "killed": killed }),
        )?;
    }
    drop(guards);
    Ok((outcome?, report))
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
        if let Some((role, status)) = children.take_exited() {
            bail!(
                "the {} process exited before it was ready ({status})",
                role.as_str()
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
