//! The driver of a multi-process run: the run's parts composed, and the clock driven.
//!
//! Lockstep: the driver grants tick `j` and waits until every sample of the tick (and the
//! plan of a sample it starts) has come, records it, and only then grants `j + 1`, so the
//! record is part of the handshake and loses nothing. It clears its wake-ups and checks
//! the processes right after the grant, while the roles step, and then polls shared
//! memory for the tick ([`runtime::wait::lockstep_poll`]) before it blocks. Real time:
//! it starts the clock and records ticks as they complete, counting every tick it never
//! receives whole.
//!
//! Each part owns its state: [`Session`] the ports, the schedule and the clock;
//! [`Children`] the processes; [`Intake`] what was received and not recorded yet;
//! [`Recorder`] the record (its sinks: the files, the status line) and, with its judge, the
//! outcome; [`Supervisor`] status reports, failed producers, dead nodes and restarts;
//! [`SwapServer`] the swaps.

use super::intake::Intake;
use super::session::Session;
use super::supervision::{Supervisor, clean_dead_nodes};
use super::swap_server::{Parts, SwapServer};
use super::{POLL, START_LEAD, TICK_TIMEOUT};
use crate::children::Children;
use anyhow::bail;
use iceoryx2::prelude::{WaitSet, ipc::Service};
use protocol::task::GoalChange;
use protocol::{PlantKind, Role, Scenario};
use record::judge::Outcome;
use record::{Event, ProcessReport, Recorder};
use runtime::clock::monotonic_ns;
use runtime::ipc;
use runtime::wait::lockstep_poll;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// How long the robot must have been commanded to stand (by its DFL, or its plant's
/// watchdog) before an aborted real-time run ends, s.
const AT_REST_FOR_S: f64 = 0.2;
/// The longest an aborted real-time run waits for the robot to come to rest.
const BRAKE_TIMEOUT: Duration = Duration::from_secs(5);

/// A run while it is driven.
pub(super) struct Driver<'a> {
    scenario: &'a Scenario,
    /// The run's ports, processes and record, as the swap server works with them too.
    parts: Parts<'a>,
    intake: Intake,
    supervisor: Supervisor,
    swaps: SwapServer,
    stop: &'a AtomicBool,
    /// Goals set while the run drives.
    goals_set: u32,
    /// Lockstep held to real time (a live view's `live.pace`).
    pub pace: Option<crate::pace::Pace>,
    /// Real time: since when the run, which must end aborted, waits for the DFL to brake
    /// the robot to rest.
    aborting: Option<Instant>,
    /// Whether it has braked the robot to rest once: a fleet's robot, whose pipeline
    /// runs on unrecorded, is not braked again.
    braked: bool,
}

impl<'a> Driver<'a> {
    pub fn new(
        scenario: &'a Scenario,
        session: &'a Session,
        children: &'a mut Children,
        recorder: &'a mut Recorder,
        stop: &'a AtomicBool,
    ) -> Driver<'a> {
        Driver {
            scenario,
            parts: Parts {
                session,
                children,
                recorder,
            },
            intake: Intake::new(scenario, session.clock().mode()),
            supervisor: Supervisor::new(&scenario.supervision, robot::watched_keys(scenario)),
            swaps: SwapServer::new(scenario),
            stop,
            goals_set: 0,
            pace: None,
            aborting: None,
            braked: false,
        }
    }

    /// Lockstep: every tick granted, whole, recorded and judged before the next.
    pub fn lockstep(&mut self, waitset: &WaitSet<Service>) -> anyhow::Result<Outcome> {
        let ticks = self.scenario.tick_count();
        for tick in 0..=ticks {
            if let Some(pace) = &mut self.pace {
                pace.wait(tick);
            }
            self.set_requested_goal(tick)?;
            self.parts.session.grant(tick)?;
            self.take_now()?;
            if let Some(outcome) = self.check()? {
                return Ok(outcome);
            }
            let mut taken = Ok(());
            lockstep_poll(|| {
                taken = self.intake.take_from_memory(self.parts.session);
                taken.is_err() || self.intake.has_whole(tick)
            });
            taken?;
            let mut last_progress = Instant::now();
            while !self.intake.has_whole(tick) {
                if let Some(outcome) = self.check()? {
                    return Ok(outcome);
                }
                if last_progress.elapsed() > TICK_TIMEOUT {
                    bail!("tick {tick} made no progress for {TICK_TIMEOUT:?}: a process hung");
                }
                let before = self.intake.filed();
                self.take(waitset)?;
                if self.intake.filed() != before {
                    last_progress = Instant::now();
                }
            }
            if let Some(outcome) = self.record_tick(tick)? {
                return Ok(outcome);
            }
            self.serve_swaps()?;
            if let Some(outcome) = self.await_replacements(waitset)? {
                return Ok(outcome);
            }
        }
        Ok(self.parts.recorder.end_of_run(None))
    }

    /// Lockstep, a fleet's ([`super::fleet`]): grants tick `tick` (with the goal a live
    /// view's client sent, while `recording`); an outcome when the run must end. What
    /// comes is taken by [`Driver::poll_whole`], and each wake-up cleared as it fires
    /// ([`Driver::clear_fired`]).
    pub fn grant(&mut self, tick: u64, recording: bool) -> anyhow::Result<Option<Outcome>> {
        if recording {
            self.set_requested_goal(tick)?;
        }
        self.parts.session.grant(tick)?;
        let outcome = self.check()?;
        Ok(self.ended(outcome))
    }

    /// A fleet's: `outcome`, and when there is one the robot's record takes no more goals
    /// from a live view's client (its robot drives on, a track to the others). Every
    /// outcome a fleet's executor takes from a driver passes here.
    pub fn ended(&mut self, outcome: Option<Outcome>) -> Option<Outcome> {
        if outcome.is_some() {
            self.parts.recorder.stop_taking_goals();
        }
        outcome
    }

    /// Lockstep, a fleet's: clears the wake-ups of the listener that fired, the status's
    /// (`None`, whose messages are taken with it) or the data input's at `input` of
    /// [`Session::inputs`](super::session::Session::inputs). Its samples are taken from
    /// shared memory next ([`Driver::poll_whole`]).
    pub fn clear_fired(&mut self, input: Option<usize>) -> anyhow::Result<()> {
        match input {
            None => self.supervisor.take_status(
                self.parts.session,
                self.parts.children,
                self.parts.recorder,
            ),
            Some(i) => {
                if let Some(input) = self.parts.session.inputs().nth(i) {
                    input.clear_wakeups();
                }
                Ok(())
            }
        }
    }

    /// Lockstep, a fleet's: whether tick `tick` is whole, taken from shared memory alone
    /// without the checks of [`Driver::check`].
    pub fn poll_whole(&mut self, tick: u64) -> anyhow::Result<bool> {
        self.intake.take_from_memory(self.parts.session)?;
        Ok(self.intake.has_whole(tick))
    }

    /// What was received and not recorded yet ([`Intake::filed`]): a wait made progress
    /// when it changed.
    pub fn filed(&self) -> usize {
        self.intake.filed()
    }

    /// Lockstep, a fleet's: the true position at whole tick `tick`, which is recorded and
    /// judged when `recording` (an outcome: the robot's record ends), else dropped.
    pub fn take_tick(
        &mut self,
        tick: u64,
        recording: bool,
    ) -> anyhow::Result<(Option<[f64; 2]>, Option<Outcome>)> {
        let slot = self.intake.take_slot(tick);
        let position = slot.truth.map(|t| [t.pose[0], t.pose[1]]);
        if !recording {
            self.intake.drop_plans();
            return Ok((position, None));
        }
        let no_route = self.intake.record_plans(self.parts.recorder)?;
        let outcome = self.record_slot(tick, slot)?.or(no_route);
        Ok((position, self.ended(outcome)))
    }

    /// Real time, a fleet's: starts the clock, tick 0 at monotonic `start_ns`.
    pub fn start_at(&mut self, start_ns: u64) -> anyhow::Result<()> {
        self.parts.session.start(start_ns)?;
        self.parts.recorder.event(Event::ClockStarted {
            tick0_monotonic_ns: start_ns,
        })?;
        Ok(())
    }

    /// The deadlines its record counted as missed so far.
    pub fn deadline_misses(&self) -> u64 {
        self.parts.recorder.deadline_misses()
    }

    /// Real time, a fleet's: takes what came, checks the processes, and records (when
    /// `recording`, else drops) every tick due, handing each tick's true position to
    /// `seen`. An outcome when the robot's record ends or its run must end.
    pub fn record_due(
        &mut self,
        recording: bool,
        seen: &mut impl FnMut(u64, [f64; 2]),
    ) -> anyhow::Result<Option<Outcome>> {
        self.take_now()?;
        if let Some(outcome) = self.check_or_brake(recording)? {
            return Ok(self.ended(Some(outcome)));
        }
        let planned = match recording {
            true => self.intake.record_plans(self.parts.recorder)?,
            false => {
                self.intake.drop_plans();
                None
            }
        };
        let mut outcome = planned.filter(|_| self.aborting.is_none());
        if recording && self.aborting.is_none() && outcome.is_none() {
            let now = self.parts.session.clock().now_tick().unwrap_or(0);
            self.set_requested_goal(now)?;
        }
        while let Some(slot) = (self.intake).next_due(recording.then_some(self.parts.recorder))? {
            let tick = self.intake.cursor - 1;
            if let Some(truth) = &slot.truth {
                seen(tick, [truth.pose[0], truth.pose[1]]);
            }
            if recording && outcome.is_none() {
                outcome = self.record_slot(tick, slot)?.map(|o| self.aborted_as(o));
            }
        }
        Ok(self.ended(outcome))
    }

    /// Lockstep: holds the clock while a replacement has not joined the run, so that a
    /// swap comes at the same simulated time however long its process takes to start (on
    /// another host, longer than the rest of a short run takes in lockstep). A replacement
    /// that exits, or does not publish within the swap's timeout, fails its swap, and the
    /// run goes on.
    fn await_replacements(
        &mut self,
        waitset: &WaitSet<Service>,
    ) -> anyhow::Result<Option<Outcome>> {
        while self
            .swaps
            .awaiting_join(|role, epoch| self.supervisor.has_joined(role, epoch))
        {
            if let Some(outcome) = self.check()? {
                return Ok(Some(outcome));
            }
            self.take(waitset)?;
            self.serve_swaps()?;
        }
        Ok(None)
    }

    /// Real time: the clock started, and ticks recorded and judged as they complete. A run
    /// that must end aborted while the robot can still be braked (a producer lost with no
    /// restart or failover left, [`Driver::can_brake_to_rest`]) goes on, recorded, until
    /// it is at rest (commanded to stand for [`AT_REST_FOR_S`], or [`BRAKE_TIMEOUT`]), and
    /// then ends.
    pub fn realtime(&mut self, waitset: &WaitSet<Service>) -> anyhow::Result<Outcome> {
        let start_ns = monotonic_ns() + START_LEAD.as_nanos() as u64;
        self.parts.session.start(start_ns)?;
        self.parts.recorder.event(Event::ClockStarted {
            tick0_monotonic_ns: start_ns,
        })?;
        let end_ns = self.parts.session.clock().at_ns(self.scenario.duration_s);
        let give_up_ns = end_ns.unwrap_or(start_ns) + 5_000_000_000;
        loop {
            if let Some(outcome) = self.check_or_brake(true)? {
                return Ok(outcome);
            }
            if monotonic_ns() > give_up_ns {
                if self.aborting.is_some() {
                    return Ok(Outcome::Aborted);
                }
                bail!("the run did not finish within 5 s after its end: a process hung");
            }
            self.take(waitset)?;
            let planned = self.intake.record_plans(self.parts.recorder)?;
            if self.aborting.is_none() {
                if let Some(outcome) = planned {
                    return Ok(outcome);
                }
                self.serve_swaps()?;
                let now = self.parts.session.clock().now_tick().unwrap_or(0);
                self.set_requested_goal(now)?;
            }
            while let Some(slot) = self.intake.next_due(Some(self.parts.recorder))? {
                let tick = self.intake.cursor - 1;
                if let Some(outcome) = self.record_slot(tick, slot)? {
                    return Ok(self.aborted_as(outcome));
                }
            }
        }
    }

    /// Real time: [`Driver::check`], except that a run which must end aborted while the
    /// robot can still be braked goes on, recorded (`recording`), until the DFL or the
    /// plant's watchdog has braked it to rest (commanded to stand for [`AT_REST_FOR_S`],
    /// or [`BRAKE_TIMEOUT`]): the record shows the stop. The outcome once the run ends.
    fn check_or_brake(&mut self, recording: bool) -> anyhow::Result<Option<Outcome>> {
        if let Some(since) = self.aborting {
            if self.stop.load(Ordering::Relaxed) {
                return Ok(Some(Outcome::Interrupted));
            }
            let braked = self.parts.recorder.commanded_rest_for_s() >= AT_REST_FOR_S
                || since.elapsed() > BRAKE_TIMEOUT;
            self.parts.children.kill_overdue();
            if !braked {
                return Ok(None);
            }
            return Ok(Some(self.aborted_as(Outcome::Aborted)));
        }
        match self.check()? {
            Some(Outcome::Aborted) if recording && !self.braked && self.can_brake_to_rest() => {
                self.parts.recorder.event(Event::BrakingToRest {})?;
                self.aborting = Some(Instant::now());
                Ok(None)
            }
            outcome => Ok(outcome),
        }
    }

    /// The outcome a record ends with; braking to rest, that ends the braking, and every
    /// outcome but a collision is the abort's.
    fn aborted_as(&mut self, outcome: Outcome) -> Outcome {
        if self.aborting.take().is_none() {
            return outcome;
        }
        self.braked = true;
        match outcome {
            Outcome::Collided => outcome,
            _ => Outcome::Aborted,
        }
    }

    /// Whether something can still bring the robot to rest before an aborted run ends:
    /// the plant runs, and the DFL with its fallbacks (the shifted plan, then the brake)
    /// or, without a DFL (lost with its host), the simulated base's own watchdog
    /// (`plant.command_timeout_s`).
    fn can_brake_to_rest(&self) -> bool {
        let runs = |role: Role| {
            let epoch = self.parts.session.schedule().current(role);
            self.parts.children.pid(role, epoch).is_some()
        };
        runs(Role::Plant) && (runs(Role::Dfl) || self.scenario.plant.kind == PlantKind::Sim)
    }

    /// Records and judges tick `tick` (with the plans received before it); the tick
    /// after the last ends the run.
    fn record_tick(&mut self, tick: u64) -> anyhow::Result<Option<Outcome>> {
        let slot = self.intake.take_slot(tick);
        let no_route = self.intake.record_plans(self.parts.recorder)?;
        Ok(self.record_slot(tick, slot)?.or(no_route))
    }

    fn record_slot(
        &mut self,
        tick: u64,
        slot: super::intake::TickSlot,
    ) -> anyhow::Result<Option<Outcome>> {
        if tick == self.scenario.tick_count() {
            return Ok(Some(self.parts.recorder.end_of_run(slot.truth.as_ref())));
        }
        self.intake.record(slot, self.parts.recorder)
    }

    /// Takes everything received, without waiting.
    fn take_now(&mut self) -> anyhow::Result<()> {
        self.intake.take(self.parts.session)?;
        self.supervisor
            .take_status(self.parts.session, self.parts.children, self.parts.recorder)
    }

    /// Waits for input (at most [`POLL`]) and takes everything received.
    fn take(&mut self, waitset: &WaitSet<Service>) -> anyhow::Result<()> {
        ipc::wait(waitset, POLL)?;
        self.take_now()
    }

    /// A goal a sink took from outside (a live view's client), set for every process and
    /// the record ([`GoalChange::set_at`]) at tick `now_tick`.
    fn set_requested_goal(&mut self, now_tick: u64) -> anyhow::Result<()> {
        let Some(goal) = self.parts.recorder.requested_goal() else {
            return Ok(());
        };
        self.goals_set += 1;
        let inner_steps = self.scenario.timing.inner_steps;
        let change = GoalChange::set_at(self.goals_set, goal, now_tick, inner_steps);
        self.parts.session.set_goal(change)?;
        self.parts.recorder.goal_set(&change)?;
        Ok(())
    }

    /// Between ticks: the swaps moved on.
    fn serve_swaps(&mut self) -> anyhow::Result<()> {
        let recorded = self.intake.cursor;
        let now_tick = self
            .parts
            .session
            .clock()
            .now_tick()
            .unwrap_or(0)
            .max(recorded);
        self.swaps.serve(&mut self.parts, now_tick, recorded)
    }

    /// Ends the run on Ctrl-C; supervises; handles a process that exited: a retired one
    /// is forgotten, a failed replacement cancels its swap, and a dead active process is
    /// cleaned up after and then replaced by its warming replacement if there is one, else
    /// restarted per the scenario's supervision policy, else the run ends as aborted.
    pub fn check(&mut self) -> anyhow::Result<Option<Outcome>> {
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        self.parts.children.kill_overdue();
        self.supervisor
            .contain(self.parts.session, self.parts.children, self.parts.recorder)?;
        self.supervisor
            .watch_nodes(self.parts.children, self.parts.recorder)?;
        if let Some(host) = self
            .parts
            .children
            .remote
            .as_ref()
            .and_then(|r| r.take_lost())
        {
            return self.lose_host(&host);
        }
        let Some((proc, status)) = self.parts.children.take_exited() else {
            return Ok(None);
        };
        let (role, epoch) = (proc.role, proc.epoch);
        let cleaned = clean_dead_nodes(
            self.parts.children,
            self.parts.recorder,
            Some((role, epoch)),
        )?;
        if proc.retire_by.is_some() {
            self.parts.recorder.event(Event::Retired {
                role,
                epoch,
                status,
            })?;
            return Ok(None);
        }
        if self
            .swaps
            .replacement_exited(&mut self.parts, role, epoch, &status)?
        {
            return Ok(None);
        }
        // A terminal's Ctrl-C reaches the whole process group: the children may see it a
        // moment before the orchestrator's handler runs.
        std::thread::sleep(Duration::from_millis(20));
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        tracing::warn!(
            "the {} process (epoch {epoch}) died: {status}{}",
            role.as_str(),
            self.parts.children.death_notes(&proc),
        );
        self.parts.recorder.event(Event::Crashed {
            role,
            epoch,
            status,
            nodes_cleaned: cleaned,
        })?;
        if self.swaps.promote(&mut self.parts, role)? {
            return Ok(None);
        }
        let restarted = self.supervisor.restart(
            role,
            self.parts.session,
            self.parts.children,
            self.parts.recorder,
        )?;
        Ok((!restarted).then_some(Outcome::Aborted))
    }

    /// The agent of `host` is gone (docs/hosts.md): its processes are as good as crashed.
    /// Each active producer among them fails over to this host, or the run ends aborted.
    fn lose_host(&mut self, host: &str) -> anyhow::Result<Option<Outcome>> {
        let gone = self.parts.children.forget_host(host);
        let roles: Vec<Role> = gone
            .iter()
            .filter(|p| self.parts.session.schedule().current(p.role) == p.epoch)
            .map(|p| p.role)
            .collect();
        self.parts.recorder.event(Event::HostLost {
            host: host.to_string(),
            roles: roles.clone(),
        })?;
        for role in roles {
            let failed_over = self.supervisor.fail_over(
                role,
                self.parts.session,
                self.parts.children,
                self.parts.recorder,
            )?;
            if !failed_over {
                return Ok(Some(Outcome::Aborted));
            }
        }
        Ok(None)
    }

    /// After the clock has stopped with `outcome`: records the plans still held, answers
    /// every swap that did not happen, and fills `report` with the run's counts.
    pub fn finish(
        mut self,
        outcome: anyhow::Result<Outcome>,
        report: &mut ProcessReport,
    ) -> anyhow::Result<Outcome> {
        let outcome =
            outcome.and_then(|o| self.intake.record_plans(self.parts.recorder).map(|_| o));
        self.swaps.finish(&mut self.parts)?;
        self.intake.report(report);
        report.restarts = self.supervisor.restarts();
        report.swaps = self.swaps.done();
        report.failed_swaps = self.swaps.failed();
        report.rejected_samples = self.supervisor.take_rejected();
        outcome
    }
}
