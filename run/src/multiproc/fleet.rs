//! A fleet across processes, in lockstep or in real time (docs/fleet.md): one set of role processes per
//! robot, each with its robot's id (its services under `robot<id>/`), all reading the
//! fleet's `scenario.toml` and driving their robot's member. One driver per robot
//! ([`Driver`]) keeps its session, children and record; in lockstep this loop grants each
//! robot its next tick once its tick before is whole and recorded, every robot's tick
//! `j - 1` whole before any is granted a tick `j` at which they start together
//! ([`Fleet::starts_together`]), and judges the robots against each other tick by tick
//! once every robot has come that far. Each robot's tracker takes the others' truths,
//! estimates and plans itself at those ticks, from before its tick only
//! ([`tracker::Peers`]), so the run gives the bytes of the fleet in process.
//!
//! A robot whose record has ended (it reached its goal) drives on unrecorded, a track to
//! the others, until every robot's record has ended.

use super::driver::Driver;
use super::session::Session;
use super::{
    HostsSetup, POLL, START_LEAD, STOP_TIMEOUT, TICK_TIMEOUT, remove_dead_runs, wait_until_ready,
};
use crate::children::{Children, LOG_DIR};
use crate::remote::{RemoteHosts, Whose};
use crate::sinks::Recording;
use crate::status_line::FleetStatus;
use anyhow::{Context, bail};
use iceoryx2::prelude::{WaitSet, ipc::Service};
use protocol::{ControlCommand, Validated};
use record::event::{Event, Ready};
use record::fleet::{FleetJudge, FleetSummary};
use record::judge::Outcome;
use record::{ProcessReport, Recorder};
use runtime::clock::RunMode;
use runtime::clock::monotonic_ns;
use runtime::ipc;
use runtime::wakes::Wakes;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Each robot's part of the run, by robot id: its member's scenario, its session, its
/// processes and its record.
#[derive(Default)]
struct Robots {
    scenarios: Vec<Validated>,
    sessions: Vec<Session>,
    children: Vec<Children>,
    recorders: Vec<Recorder>,
    /// The fleet's live view, which every robot's record joins.
    view: Option<live::FleetView>,
}

/// Runs the fleet `scenario` in lockstep as role processes on iceoryx2 resources named
/// with `prefix`, and writes `out`: the fleet's `scenario.toml` and `summary.json`, and
/// `robot<id>/` for each robot. Whatever happens, every process is stopped and the run's
/// resources are removed before this returns.
pub fn run(
    scenario: &Validated,
    out: &Path,
    (mode, prefix): (RunMode, &str),
    hosts: &HostsSetup,
    recording: Recording,
    stop: &AtomicBool,
) -> anyhow::Result<FleetSummary> {
    let started = Instant::now();
    remove_dead_runs();
    ipc::admit_robots(scenario.robot_count());
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let scenario_file = out.join("scenario.toml");
    std::fs::write(&scenario_file, scenario.to_toml())
        .with_context(|| format!("writing {}", scenario_file.display()))?;
    ipc::register_run(prefix, out).context("registering the run")?;
    let result = drive(
        scenario,
        out,
        (mode, prefix),
        hosts,
        recording,
        stop,
        started,
    );
    if let Err(e) = ipc::end_run(prefix) {
        tracing::warn!("cleaning up the run's iceoryx2 resources: {e}");
    }
    let summary = result?;
    summary.write(out)?;
    crate::sinks::merge_fleet_mcap(out, scenario.robot_count());
    Ok(summary)
}

/// Each robot's part opened and its processes started, one robot after the other (a robot
/// on another host: its host joined first).
fn open_robots(
    scenario: &Validated,
    out: &Path,
    (mode, prefix): (RunMode, &str),
    hosts: &HostsSetup,
    recording: Recording,
    robots: &mut Robots,
) -> anyhow::Result<()> {
    robots.view = crate::sinks::fleet_view(scenario, recording)?;
    for id in 0..scenario.robot_count() {
        let member = (scenario.member(id))
            .validated(&format!("robot {id} of the fleet"))
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let dir = out.join(format!("robot{id}"));
        let mut recorder =
            crate::sinks::member_recorder(&member, id, &dir, recording, robots.view.as_ref())?;
        let session = Session::open_for(prefix, &member, mode, id as u32)?;
        let control = session.control.publisher_id();
        let whose = Whose {
            robot: id as u32,
            fleet: Some(scenario),
        };
        let remote = (!member.hosts.names().is_empty())
            .then(|| {
                let remote = RemoteHosts::connect(
                    &member,
                    mode,
                    prefix,
                    whose,
                    &hosts.endpoints,
                    &hosts.security,
                    control,
                )?;
                super::record_joined(&remote, &mut recorder)?;
                anyhow::Ok(remote)
            })
            .transpose()
            .with_context(|| format!("robot {id}"))?;
        let children = Children::new(
            &out.join("scenario.toml"),
            prefix,
            id as u32,
            mode,
            control,
            Vec::new(),
            remote,
        )?;
        let mut children = children.with_logs(&dir.join(LOG_DIR));
        // Pushed before its processes start, so that they are stopped whatever follows.
        let spawned = children.spawn_all(member.roles());
        for p in &children.list {
            recorder.event(Event::Spawned {
                role: p.role,
                pid: p.pid(),
                host: p.host().map(String::from),
            })?;
        }
        robots.scenarios.push(member);
        robots.sessions.push(session);
        robots.children.push(children);
        robots.recorders.push(recorder);
        spawned?;
    }
    robots.view.iter().for_each(live::FleetView::announce);
    Ok(())
}

/// Starts every robot's processes, drives the fleet and stops them all.
fn drive(
    scenario: &Validated,
    out: &Path,
    (mode, prefix): (RunMode, &str),
    hosts: &HostsSetup,
    recording: Recording,
    stop: &AtomicBool,
    started: Instant,
) -> anyhow::Result<FleetSummary> {
    let mut robots = Robots::default();
    let opened = open_robots(scenario, out, (mode, prefix), hosts, recording, &mut robots);
    // Real time: the orchestrator's recording at its tier, below every role.
    let _recording_tier = (mode == RunMode::Realtime)
        .then(|| crate::scheduling::orchestrator(&scenario.realtime))
        .flatten();
    let shown = Fleet::shown(scenario, mode, recording);
    let driven =
        opened.and_then(|()| drive_opened(scenario, prefix, &mut robots, mode, shown, stop));
    for session in &robots.sessions {
        let _ = session.command(ControlCommand::Stop);
    }
    let Robots {
        scenarios,
        children,
        recorders,
        view,
        ..
    } = robots;
    let processes: Vec<ProcessReport> = children.iter().map(processes_of).collect();
    let exits: Vec<_> = (children.into_iter())
        .map(|mut c| {
            let exits = c.shut_down(STOP_TIMEOUT);
            (exits, c.remote.as_ref().map(super::end_hosts))
        })
        .collect();
    let ended = scenarios.into_iter().zip(exits).zip(recorders);
    let (outcomes, judge, reports, simulated_s) = driven?;
    let wall_s = started.elapsed().as_secs_f64();
    let mut summaries = Vec::with_capacity(outcomes.len());
    let mut deadlocks = Vec::with_capacity(outcomes.len());
    let signal = crate::stop::received();
    let reports = reports.into_iter().zip(processes);
    for ((((scenario, exits), mut recorder), outcome), (mut report, processes)) in
        ended.zip(outcomes).zip(reports)
    {
        let (exits, links) = exits;
        report.pids = processes.pids;
        report.hosts = processes.hosts;
        report.peak_rss_kib = processes.peak_rss_kib;
        if let Some((orchestrator_bridge, links)) = links {
            (report.orchestrator_bridge, report.links) = (orchestrator_bridge, links);
        }
        super::record_exits(&mut recorder, exits)?;
        deadlocks.push(recorder.deadlocks_broken());
        let summary = recorder.finish(
            &scenario,
            mode.as_str(),
            outcome,
            wall_s,
            Some(report),
            signal,
        )?;
        summaries.push(summary);
    }
    if let Some(view) = view {
        view.finish().context("closing the fleet's live view")?;
    }
    Ok(FleetSummary::of(
        &summaries,
        &judge,
        &deadlocks,
        simulated_s,
        wall_s,
    ))
}

/// The pids of a robot's processes (and the orchestrator's), the hosts its roles were
/// placed on (also once a host is lost) and their peak resident memory so far.
fn processes_of(children: &Children) -> ProcessReport {
    let mut report = ProcessReport::default();
    report
        .pids
        .insert("orchestrator".into(), std::process::id());
    for p in &children.list {
        report.pids.insert(p.role.as_str().into(), p.pid());
    }
    if let Some(remote) = &children.remote {
        for role in protocol::Role::ALL {
            if let Some(host) = remote.placed_on(role) {
                report.hosts.insert(role.as_str().into(), host.into());
            }
        }
    }
    super::record_peak_rss(children, &mut report);
    report
}

type Driven = (Vec<Outcome>, FleetJudge, Vec<ProcessReport>, f64);

/// Waits until every robot's processes are ready, then grants, waits for, records and
/// judges every tick of every robot until every robot's record has ended.
fn drive_opened(
    scenario: &Validated,
    prefix: &str,
    robots: &mut Robots,
    mode: RunMode,
    shown: (Option<FleetStatus>, Option<crate::pace::Pace>),
    stop: &AtomicBool,
) -> anyhow::Result<Driven> {
    let Robots {
        scenarios,
        sessions,
        children,
        recorders,
        ..
    } = robots;
    // Each robot's processes waited for on its own status alone (another's readiness
    // left unread would wake every wait), then one wait set for the run.
    for id in 0..sessions.len() {
        let starting = ipc::waitset(false)?;
        let _guard = sessions[id].status.attach(&starting)?;
        wait_until_ready(
            &scenarios[id],
            &sessions[id],
            &starting,
            &mut children[id],
            stop,
        )?;
        recorders[id].event(Event::Ready(Ready::Run {
            iceoryx2_prefix: prefix.to_string(),
        }))?;
    }
    let waitset = ipc::waitset(false)?;
    // Each listener's robot, and its status's (`None`) or its data input's at that index
    // of `Session::inputs`, in the order of `guards`.
    let mut guards = Vec::new();
    let mut listeners = Vec::new();
    for (id, session) in sessions.iter().enumerate() {
        guards.push(session.status.attach(&waitset)?);
        listeners.push((id, None));
        for (i, input) in session.inputs().enumerate() {
            if input.listener().is_some() {
                guards.push(ipc::attach_input(&waitset, input)?);
                listeners.push((id, Some(i)));
            }
        }
    }
    let mut wakes = (Wakes::new(&guards), listeners);
    let parts = scenarios
        .iter()
        .zip(sessions.iter())
        .zip(children.iter_mut());
    let mut drivers: Vec<Driver> = (parts.zip(recorders.iter_mut()))
        .map(|(((s, session), c), r)| Driver::new(s, session, c, r, stop))
        .collect();
    let mut fleet = Fleet::new(scenario, scenarios, shown);
    let driven = match mode {
        RunMode::Lockstep => lockstep(&mut drivers, &mut fleet, (&waitset, &mut wakes)),
        RunMode::Realtime => realtime(&mut drivers, &mut fleet, &waitset, stop),
    };
    drop(fleet.status.take());
    let Fleet {
        judge, outcomes, ..
    } = fleet;
    let mut reports = Vec::with_capacity(drivers.len());
    let mut ended = Vec::with_capacity(drivers.len());
    for (driver, outcome) in drivers.into_iter().zip(&outcomes) {
        let mut report = ProcessReport {
            iceoryx2_prefix: prefix.to_string(),
            ..ProcessReport::default()
        };
        let outcome = driven
            .as_ref()
            .map(|_| outcome.unwrap_or(Outcome::Interrupted))
            .map_err(|e| anyhow::anyhow!("{e:#}"));
        ended.push(driver.finish(outcome, &mut report)?);
        reports.push(report);
    }
    let simulated_s = driven?;
    drop(guards);
    Ok((ended, judge, reports, simulated_s))
}

/// The fleet as it is driven: the judge of the robots against each other, and each
/// robot's outcome once its record has ended.
struct Fleet {
    judge: FleetJudge,
    /// Where each robot starts, m.
    starts: Vec<[f64; 2]>,
    outcomes: Vec<Option<Outcome>>,
    dt_s: f64,
    ticks: u64,
    /// `M`, and the inner ticks of a perception tick.
    ticks_per_sample: u64,
    perception_ticks: u64,
    /// The fleet's status line, if the run has one.
    status: Option<FleetStatus>,
    /// Lockstep held to real time for a live view (`live.pace`).
    pace: Option<crate::pace::Pace>,
}

impl Fleet {
    /// The fleet of `scenario` (its robots', `members`) before its first tick.
    fn new(
        scenario: &Validated,
        members: &[Validated],
        (status, pace): (Option<FleetStatus>, Option<crate::pace::Pace>),
    ) -> Fleet {
        let radii = (0..scenario.robot_count())
            .map(|id| scenario.radius_of(id))
            .collect();
        Fleet {
            judge: FleetJudge::new(radii),
            starts: (members.iter())
                .map(|s| [s.robot.start[0], s.robot.start[1]])
                .collect(),
            outcomes: vec![None; members.len()],
            dt_s: scenario.timing.dt_s(),
            ticks: scenario.tick_count(),
            ticks_per_sample: scenario.timing.ticks_per_sample(),
            perception_ticks: scenario.perception_ticks(),
            status,
            pace,
        }
    }

    /// How the fleet's run of `scenario` in `mode` is shown while it drives: its status
    /// line, and in lockstep its pace for a live view.
    fn shown(
        scenario: &Validated,
        mode: RunMode,
        recording: Recording,
    ) -> (Option<FleetStatus>, Option<crate::pace::Pace>) {
        let robots = scenario.robot_count();
        let status = FleetStatus::of(recording.status_line, scenario.duration_s, robots);
        let pace = crate::pace::Pace::of(scenario, recording);
        (status, pace.filter(|_| mode == RunMode::Lockstep))
    }

    /// Lockstep: whether every robot must have completed the tick before `tick` before
    /// any is granted it: at every sample start and perception tick, where a robot's
    /// tracker and lidar take the others' samples from before it, and at least every
    /// [`ipc::MAX_TICKS_APART`] ticks.
    fn starts_together(&self, tick: u64) -> bool {
        tick.is_multiple_of(self.ticks_per_sample)
            || tick.is_multiple_of(self.perception_ticks)
            || tick.is_multiple_of(ipc::MAX_TICKS_APART)
    }

    /// The status line, once the robots are judged through `ticks` ticks.
    fn show(&mut self, ticks: u64, drivers: &[Driver]) {
        if let Some(status) = &mut self.status {
            let outcomes = self.outcomes.iter().copied();
            let misses = drivers.iter().map(Driver::deadline_misses);
            status.show(ticks as f64 * self.dt_s, outcomes, misses, &self.judge);
        }
    }
}

/// The run's wait set's wake-ups, and whose listener each is: a robot's, its status's
/// (`None`) or its data input's at that index of [`Session::inputs`].
type FleetWakes = (Wakes, Vec<(usize, Option<usize>)>);

/// Lockstep: each robot's ticks granted one by one, each once the one before is whole and
/// recorded, until every robot's record has ended; the time simulated, s. The robots run
/// apart between the ticks at which they start together ([`Fleet::starts_together`]):
/// a robot takes another's samples only at those (its tracker and its lidar, from before
/// the tick), so how far one has run ahead of another changes nothing they publish, and
/// a core that has finished its robots' tick goes on with their next rather than waiting
/// for the other core's.
fn lockstep(
    drivers: &mut [Driver],
    fleet: &mut Fleet,
    (waitset, (wakes, listeners)): (&WaitSet<Service>, &mut FleetWakes),
) -> anyhow::Result<f64> {
    let mut ticks = LockstepTicks::new(fleet);
    let (mut filed, mut last_progress) = (0, Instant::now());
    let mut last_check = Instant::now();
    loop {
        if !ticks.grant(drivers, fleet)? {
            return Ok(ticks.slowest() as f64 * fleet.dt_s); // that tick never completed
        }
        if ticks.next.iter().all(|&n| n > ticks.last_tick) {
            break;
        }
        // Every robot's tick taken from shared memory if whole, then a block; after it
        // only the listeners that fired are cleared (the wait set fires while any of them
        // is left), and every one after a block that timed out ([`Wakes`]). The
        // processes checked every `POLL`.
        if ticks.take_whole(drivers, fleet)? {
            last_progress = Instant::now();
            continue;
        }
        let now_filed: usize = drivers.iter().map(Driver::filed).sum();
        if now_filed != filed {
            (filed, last_progress) = (now_filed, Instant::now());
        } else if last_progress.elapsed() > TICK_TIMEOUT {
            let tick = ticks.slowest();
            bail!("tick {tick} made no progress for {TICK_TIMEOUT:?}: a process hung");
        }
        if last_check.elapsed() >= POLL {
            last_check = Instant::now();
            for (id, driver) in drivers.iter_mut().enumerate() {
                if let Some(outcome) = driver.check().map(|o| driver.ended(o))?
                    && !end(&mut fleet.outcomes, id, outcome)
                {
                    return Ok(ticks.slowest() as f64 * fleet.dt_s);
                }
            }
        }
        wakes.wait(waitset, POLL)?;
        for (i, (id, input)) in listeners.iter().enumerate() {
            if wakes.to_clear(true, i) {
                drivers[*id].clear_fired(*input)?;
            }
        }
        wakes.cleared();
    }
    ticks.seen.judge(&mut fleet.judge, fleet.ticks, fleet.dt_s);
    fleet.show(ticks.seen.judged, drivers);
    Ok((ticks.last_tick + 1).min(fleet.ticks) as f64 * fleet.dt_s)
}

/// Lockstep: where each robot is in its ticks ([`lockstep`]).
struct LockstepTicks {
    /// Each robot's next tick to grant, and the tick granted and not whole yet.
    next: Vec<u64>,
    granted: Vec<Option<u64>>,
    seen: SeenTicks,
    /// The tick at which each robot's record ended.
    ended_at: Vec<Option<u64>>,
    /// The last tick driven: the run's last, or once every record has ended, the latest
    /// at which one did.
    last_tick: u64,
}

impl LockstepTicks {
    fn new(fleet: &Fleet) -> LockstepTicks {
        let robots = fleet.starts.len();
        LockstepTicks {
            next: vec![0; robots],
            granted: vec![None; robots],
            seen: SeenTicks::new(&fleet.starts),
            ended_at: vec![None; robots],
            last_tick: fleet.ticks,
        }
    }

    /// The first tick some robot has not completed.
    fn slowest(&self) -> u64 {
        self.next.iter().min().copied().unwrap_or(0)
    }

    /// Grants every robot waiting its next tick, if it may start it. False: the run must
    /// end (interrupted, or a robot's process lost with no restart left).
    fn grant(&mut self, drivers: &mut [Driver], fleet: &mut Fleet) -> anyhow::Result<bool> {
        let slowest = self.slowest();
        for (id, driver) in drivers.iter_mut().enumerate() {
            let tick = self.next[id];
            if self.granted[id].is_some()
                || tick > self.last_tick
                || (fleet.starts_together(tick) && slowest < tick)
            {
                continue;
            }
            if let Some(pace) = &mut fleet.pace {
                pace.wait(tick);
            }
            if let Some(outcome) = driver.grant(tick, fleet.outcomes[id].is_none())?
                && !end(&mut fleet.outcomes, id, outcome)
            {
                return Ok(false);
            }
            self.granted[id] = Some(tick);
        }
        Ok(true)
    }

    /// Takes, records and judges every robot's granted tick that is whole; whether one was.
    fn take_whole(&mut self, drivers: &mut [Driver], fleet: &mut Fleet) -> anyhow::Result<bool> {
        let mut progressed = false;
        for (id, driver) in drivers.iter_mut().enumerate() {
            let Some(tick) = self.granted[id] else {
                continue;
            };
            if !driver.poll_whole(tick)? {
                continue;
            }
            let (position, outcome) = driver.take_tick(tick, fleet.outcomes[id].is_none())?;
            self.seen.see(id, tick, position);
            (self.granted[id], self.next[id], progressed) = (None, tick + 1, true);
            if let Some(outcome) = outcome {
                end(&mut fleet.outcomes, id, outcome);
            }
            for (at, outcome) in self.ended_at.iter_mut().zip(&fleet.outcomes) {
                if outcome.is_some() {
                    at.get_or_insert(tick);
                }
            }
        }
        if progressed {
            if let Some(ended) = self.ended_at.iter().copied().collect::<Option<Vec<_>>>() {
                self.last_tick = self.last_tick.min(ended.into_iter().max().unwrap_or(0));
            }
            self.seen.judge(&mut fleet.judge, fleet.ticks, fleet.dt_s);
            fleet.show(self.seen.judged, drivers);
        }
        Ok(progressed)
    }
}

/// Real time: every robot's clock started at the same tick 0, and each robot's ticks
/// recorded as they complete, the robots judged against each other tick by tick once every
/// robot still recorded has come that far, until every robot's record has ended (or 5 s
/// after the run's end); the time simulated, s. A robot whose run aborts (a process lost
/// with no restart left) ends its record once its DFL, or its plant's watchdog, has braked
/// it to rest, and the others drive on.
fn realtime(
    drivers: &mut [Driver],
    fleet: &mut Fleet,
    waitset: &WaitSet<Service>,
    stop: &AtomicBool,
) -> anyhow::Result<f64> {
    let start_ns = monotonic_ns() + START_LEAD.as_nanos() as u64;
    for driver in drivers.iter_mut() {
        driver.start_at(start_ns)?;
    }
    let give_up_ns = start_ns + (fleet.ticks as f64 * fleet.dt_s * 1e9) as u64 + 5_000_000_000;
    let mut seen = SeenTicks::new(&fleet.starts);
    while fleet.outcomes.iter().any(Option::is_none) {
        if stop.load(Ordering::Relaxed) {
            end(&mut fleet.outcomes, 0, Outcome::Interrupted);
            break;
        }
        if monotonic_ns() > give_up_ns {
            bail!("the fleet's run did not finish within 5 s after its end: a process hung");
        }
        ipc::wait(waitset, POLL)?;
        for (id, driver) in drivers.iter_mut().enumerate() {
            let recording = fleet.outcomes[id].is_none();
            let outcome =
                driver.record_due(recording, &mut |tick, p| seen.see(id, tick, Some(p)))?;
            match outcome {
                Some(Outcome::Interrupted) => {
                    end(&mut fleet.outcomes, id, Outcome::Interrupted);
                }
                Some(outcome) => {
                    seen.gone[id] |= outcome == Outcome::Aborted;
                    fleet.outcomes[id].get_or_insert(outcome);
                }
                None => {}
            }
        }
        seen.judge(&mut fleet.judge, fleet.ticks, fleet.dt_s);
        fleet.show(seen.judged, drivers);
    }
    Ok(seen.judged.min(fleet.ticks) as f64 * fleet.dt_s)
}

/// Each robot's true positions by tick as its ticks are recorded, until every
/// robot has come that far ([`SeenTicks::judge`]).
struct SeenTicks {
    by_tick: std::collections::BTreeMap<u64, Vec<Option<[f64; 2]>>>,
    /// The newest tick seen of each robot.
    newest: Vec<Option<u64>>,
    /// Each robot's position at the last tick judged (at first its start).
    last: Vec<[f64; 2]>,
    /// Robots no longer waited for (their run aborted): they stay where last seen.
    gone: Vec<bool>,
    /// Ticks judged so far.
    judged: u64,
}

impl SeenTicks {
    fn new(starts: &[[f64; 2]]) -> SeenTicks {
        SeenTicks {
            by_tick: std::collections::BTreeMap::new(),
            newest: vec![None; starts.len()],
            last: starts.to_vec(),
            gone: vec![false; starts.len()],
            judged: 0,
        }
    }

    /// Robot `id` has come through `tick`, at `position` if its truth of the tick is
    /// known (else where it was at the tick before).
    fn see(&mut self, id: usize, tick: u64, position: Option<[f64; 2]>) {
        let robots = self.newest.len();
        let entry = self
            .by_tick
            .entry(tick)
            .or_insert_with(|| vec![None; robots]);
        entry[id] = position;
        self.newest[id] = self.newest[id].max(Some(tick));
    }

    /// Judges every tick up to the newest every robot still waited for has reached; a
    /// robot without that tick (a tick lost) counts where it was at the tick before.
    fn judge(&mut self, judge: &mut FleetJudge, ticks: u64, dt_s: f64) {
        let waited = (self.newest.iter().zip(&self.gone)).filter(|(_, gone)| !**gone);
        let Some(reached) = waited.map(|(newest, _)| *newest).min().flatten() else {
            return;
        };
        while self.judged <= reached && self.judged < ticks {
            let seen = self.by_tick.remove(&self.judged).unwrap_or_default();
            for (last, known) in self.last.iter_mut().zip(seen) {
                *last = known.unwrap_or(*last);
            }
            judge.tick(&self.last, dt_s);
            self.judged += 1;
        }
    }
}

/// Ends robot `id`'s record with `outcome`. False: the fleet's run must end, as the robot's
/// pipeline cannot go on (aborted) or the run was interrupted; the others' records end
/// interrupted.
fn end(outcomes: &mut [Option<Outcome>], id: usize, outcome: Outcome) -> bool {
    outcomes[id].get_or_insert(outcome);
    if outcome == Outcome::Interrupted || outcome == Outcome::Aborted {
        for o in outcomes.iter_mut().filter(|o| o.is_none()) {
            *o = Some(Outcome::Interrupted);
        }
        return false;
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robots_start_together_at_sample_starts_perception_ticks_and_every_32nd_tick() {
        let fleet = |overrides: &[&str]| {
            let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
            let scenario = crate::scenarios::load(Some("swap4"), &overrides).unwrap();
            let members: Vec<Validated> = vec![scenario.clone(); scenario.robot_count()];
            Fleet::new(&scenario, &members, (None, None))
        };
        let together = |fleet: &Fleet| -> Vec<u64> {
            (0..100).filter(|&t| fleet.starts_together(t)).collect()
        };
        // `M` = 10, a perception tick every sample.
        let expected: Vec<u64> = vec![0, 10, 20, 30, 32, 40, 50, 60, 64, 70, 80, 90, 96];
        assert_eq!(together(&fleet(&[])), expected);
        // Perception every 15 ms (3 ticks) as well.
        let every_third = fleet(&["perception.period_s=0.015"]);
        let expected: Vec<u64> = (0..100)
            .filter(|t| t % 10 == 0 || t % 3 == 0 || t % 32 == 0)
            .collect();
        assert_eq!(together(&every_third), expected);
    }
}
