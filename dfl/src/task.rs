//! The DFL role as a task ([`DflTask`]), with what surrounds the DFL in the loop and no
//! IPC: the inbox its plans arrive in, the monitor that judges every sample's deadline and
//! the watch on a silent estimator.

use crate::Dfl;
use protocol::task::{Context, Due, Outputs, Publish, Task, TaskError, header_latency};
use protocol::topics::{SCAN, TRACKS};
use protocol::{
    Actuation, CommandMode, Data, DeadlineVerdict, Estimate, Header, PLAN_MISSING, Plan,
    PlanStatus, Role, Scan, Timing, Tracks, Validated, period_ns,
};
use std::collections::VecDeque;

/// What the DFL takes: the estimator's estimates (periodic), the MPC's plans and, when
/// its check runs and an obstacle is tracked, the tracker's tracks.
// By value, as the messages come (boxing would allocate per sample).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub enum DflInput {
    Estimate(Estimate),
    Plan(Plan),
    Tracks(Tracks),
    Scan(Scan),
}
protocol::task_input!(DflInput: Estimate, Plan, Tracks, Scan);

/// What a DFL step gives: the verdict on an earlier sample's deadline, on the first
/// command of a later sample ([`DeadlineMonitor`]; published first), and the command for
/// the tick.
#[derive(Debug, Clone, Copy)]
pub struct DflOutput {
    pub verdict: Option<DeadlineVerdict>,
    pub actuation: Actuation,
}

impl Outputs for DflOutput {
    fn each(self, mut publish: impl FnMut(Data)) {
        if let Some(verdict) = self.verdict {
            publish(verdict.into());
        }
        publish(self.actuation.into());
    }
}

/// When plans reach the DFL: plan(k) that arrived `a` after `t_k` is usable from sample
/// `k + floor(a / Ts)`, the sample it arrived in. The arrival is the clock's
/// ([`Context::arrival_after_ns`]): in real time as measured (so a plan is usable once
/// received), in lockstep from its production time (a plan whose solve overran `Ts` is
/// held for the whole samples it would have taken).
pub struct PlanInbox {
    period_ns: u64,
    /// `(usable from sample, plan)` not yet offered to the DFL.
    pending: Vec<(u64, Plan)>,
    /// Newest sample a plan has been received for.
    newest_received: Option<u64>,
}

impl PlanInbox {
    pub fn new(ts_s: f64) -> PlanInbox {
        PlanInbox {
            period_ns: period_ns(ts_s),
            pending: Vec::with_capacity(8),
            newest_received: None,
        }
    }

    /// Takes plan(k) that arrived `arrival_ns` after `t_k`; returns the sample it becomes
    /// usable at.
    pub fn receive(&mut self, plan: &Plan, arrival_ns: u64) -> u64 {
        let usable = plan.sample + arrival_ns / self.period_ns;
        self.newest_received = self.newest_received.max(Some(plan.sample));
        self.pending.push((usable, *plan));
        usable
    }

    /// Whether plan(`sample`) (or a newer one) has been received.
    pub fn has_received(&self, sample: u64) -> bool {
        self.newest_received.is_some_and(|s| s >= sample)
    }

    /// Whether the DFL waits for plan(`sample`) before commanding its first tick (until
    /// the plan comes or its wait is past). A DFL that has followed the run waits for
    /// every plan; one that joined later (a restart or a replacement) cannot wait for a
    /// plan published before it listened, so it waits only once it has received the plan
    /// of the previous sample.
    pub fn waits_for(&self, sample: u64) -> bool {
        !self.has_received(sample) && (sample == 0 || self.has_received(sample - 1))
    }

    /// Offers the DFL every plan usable by `current_sample`.
    pub fn release(&mut self, current_sample: u64, dfl: &mut Dfl) {
        self.pending.retain(|(usable, plan)| {
            let arrived = *usable <= current_sample;
            if arrived {
                dfl.offer(plan);
            }
            !arrived
        });
    }
}

/// Judges every sample's deadline: plan(k) must reach the DFL, solved, by `t_k + Ts`.
/// Sample k is judged at the DFL's first command in a later sample, when its deadline has
/// passed; one sample a command, oldest first, so a sample none of whose ticks was
/// commanded from an estimate (the DFL braking alone through it, on its own clock) is
/// judged too, a command later. Judging starts at the first sample whose first tick the
/// DFL commands (a DFL that starts mid-sample has not seen that sample's plan). A backlog
/// shrinks by `timing.inner_steps - 1` samples a sample; with one tick a sample (valid,
/// used by no scenario here) it never does: each verdict then comes as many commands late
/// as samples went without one, and that many are not judged when the run ends (before,
/// they were never judged at all).
#[derive(Debug, Clone)]
pub struct DeadlineMonitor {
    period_ns: u64,
    /// `(sample, arrival after t_k in ns, status code, production ns)` of received plans
    /// not yet judged.
    arrivals: Vec<(u64, u64, u32, u64)>,
    /// The oldest sample not judged yet.
    unjudged: Option<u64>,
    /// The mode of the first command of each sample not judged yet, oldest first.
    first_modes: VecDeque<(u64, CommandMode)>,
    misses: u32,
}

impl DeadlineMonitor {
    pub fn new(ts_s: f64) -> DeadlineMonitor {
        DeadlineMonitor {
            period_ns: period_ns(ts_s),
            arrivals: Vec::with_capacity(8),
            unjudged: None,
            first_modes: VecDeque::with_capacity(4),
            misses: 0,
        }
    }

    /// Misses so far (the live counter).
    pub fn misses(&self) -> u32 {
        self.misses
    }

    /// A plan reached the DFL `arrival_ns` after the start of its sample.
    pub fn on_plan(&mut self, plan: &Plan, arrival_ns: u64) {
        if self.arrivals.iter().all(|a| a.0 != plan.sample) {
            self.arrivals.push((
                plan.sample,
                arrival_ns,
                plan.status,
                plan.solve_ns + plan.injected_delay_ns,
            ));
        }
    }

    /// A command of `sample` was given in `mode` (`first_tick`: on the sample's first
    /// tick). Returns the verdict on the oldest sample before `sample` not judged yet, if
    /// any: its fallback is the mode of its first command ([`CommandMode::Brake`] if the
    /// DFL gave it none at all).
    pub fn commanded(
        &mut self,
        sample: u64,
        first_tick: bool,
        mode: CommandMode,
    ) -> Option<DeadlineVerdict> {
        let judged = match self.unjudged {
            Some(oldest) => oldest,
            None if first_tick => {
                self.unjudged = Some(sample);
                sample
            }
            None => return None,
        };
        if self.first_modes.back().is_none_or(|(s, _)| *s < sample) {
            self.first_modes.push_back((sample, mode));
        }
        if judged >= sample {
            return None;
        }
        self.unjudged = Some(judged + 1);
        let fallback = (self.first_modes.iter())
            .find(|(s, _)| *s == judged)
            .map_or(CommandMode::Brake, |(_, mode)| *mode);
        self.first_modes.retain(|(s, _)| *s > judged);
        let found = self.arrivals.iter().find(|a| a.0 == judged).copied();
        self.arrivals.retain(|a| a.0 > judged);
        let (arrival_ns, status, production_ns) =
            found.map_or((u64::MAX, PLAN_MISSING, 0), |a| (a.1, a.2, a.3));
        let met = status == PlanStatus::Solved as u32 && arrival_ns <= self.period_ns;
        if !met {
            self.misses += 1;
        }
        Some(DeadlineVerdict {
            header: Header::default(),
            sample: judged,
            met: u32::from(met),
            status,
            production_ns,
            arrival_ns,
            fallback: fallback as u32,
            misses_total: self.misses,
        })
    }
}

/// When tracks (or scans) reach the DFL's check: those of the perception tick at or
/// before a sample's start (the ones the sample's plan was made with, `mpc::MpcTask`) are
/// waited for on its first tick, like its plan (in real time for [`PLAN_WAIT_FRACTION`] of
/// the tick, in lockstep until they come), and taken from then on; later ones wait for the
/// next sample. So the check sees the same tracks and scans in process, in lockstep and in
/// every order the topics are read in.
pub struct PerceptionInbox<M> {
    /// Inner ticks between two measurements of the tracker.
    perception_ticks: u64,
    inner_steps: u64,
    /// Messages heard and not yet taken, oldest first.
    pending: VecDeque<M>,
    /// Tick of the newest heard.
    newest: Option<u64>,
}

/// The tracks' inbox.
pub type TrackInbox = PerceptionInbox<Tracks>;

/// Estimated poses by tick, `[x_m, y_m, theta_rad]`, oldest first.
type Poses = VecDeque<(u64, [f64; 3])>;

/// Estimated poses kept to place a scan where it was taken: 0.64 s at the paper's tick,
/// more than a scan's age ([`Scan::age_ticks`], under one scan period).
const POSES_KEPT: usize = 128;

impl<M: protocol::Message> PerceptionInbox<M> {
    pub fn new(scenario: &Validated) -> PerceptionInbox<M> {
        PerceptionInbox {
            perception_ticks: scenario.perception_ticks(),
            inner_steps: scenario.timing.inner_steps as u64,
            pending: VecDeque::with_capacity(4),
            newest: None,
        }
    }

    /// Keeps `message` if it is newer than every one heard (the newest four).
    pub fn receive(&mut self, message: &M) {
        let tick = message.header().tick;
        if self.newest.is_some_and(|t| tick <= t) {
            return;
        }
        self.newest = Some(tick);
        if self.pending.len() == self.pending.capacity() {
            self.pending.pop_front();
        }
        self.pending.push_back(*message);
    }

    /// The perception tick whose tracks the command for `tick` is checked with: the last
    /// at or before its sample's start.
    fn due(&self, tick: u64) -> u64 {
        let start = tick - tick % self.inner_steps;
        start - start % self.perception_ticks
    }

    /// Whether the message due for `tick` has not come yet.
    pub fn waits_for(&self, tick: u64) -> bool {
        self.newest.is_none_or(|t| t < self.due(tick))
    }

    /// Hands `take` every message due by `tick`, oldest first.
    pub fn release(&mut self, tick: u64, mut take: impl FnMut(&M)) {
        let due = self.due(tick);
        while self.pending.front().is_some_and(|m| m.header().tick <= due) {
            if let Some(message) = self.pending.pop_front() {
                take(&message);
            }
        }
    }
}

/// Share of an inner tick the DFL waits for the plan of a new sample before it falls back
/// to the shifted previous plan (the plant only takes the command at the end of the tick,
/// so waiting within it costs nothing). In lockstep the time of a tick is never past, so
/// the DFL waits until the plan comes.
pub const PLAN_WAIT_FRACTION: f64 = 0.8;

/// The DFL role as a task ([`protocol::task`]): on each estimate, in tick order, the
/// command of the newest plan covering the tick (docs/design.md, "Deadlines and fallback"), with its plan
/// inbox, its deadline monitor and its watch on a silent estimator.
pub struct DflTask {
    dfl: Dfl,
    inbox: PlanInbox,
    monitor: DeadlineMonitor,
    watch: SilenceWatch,
    timing: Timing,
    /// Estimates not commanded yet, with their receipt latency, ns.
    queue: VecDeque<(Estimate, u64)>,
    /// The tracks, when the check runs and an obstacle is tracked.
    tracks: Option<TrackInbox>,
    /// With the check and a lidar: the scans, and the estimated poses of the newest
    /// ticks, to place a scan where it was taken.
    scans: Option<(PerceptionInbox<Scan>, Poses)>,
    /// Whether the plant takes this task's commands (not before the executor has said
    /// so, nor while it warms up as a replacement).
    commanding: bool,
    /// The serial of the goal set while the run drives that the DFL holds at (0: none).
    goal_serial: u32,
}

impl Task for DflTask {
    const ROLE: Role = Role::Dfl;
    type Input = DflInput;
    type Output = DflOutput;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<DflTask, TaskError> {
        let ts_s = scenario.timing.ts_s;
        Ok(DflTask {
            dfl: Dfl::new(scenario),
            inbox: PlanInbox::new(ts_s),
            monitor: DeadlineMonitor::new(ts_s),
            watch: SilenceWatch::default(),
            timing: scenario.timing.clone(),
            queue: VecDeque::with_capacity(16),
            tracks: (scenario.dfl.gatekeeper && scenario.takes_tracks())
                .then(|| TrackInbox::new(scenario)),
            scans: (scenario.dfl.gatekeeper && scenario.sees_with_lidar()).then(|| {
                let poses = VecDeque::with_capacity(POSES_KEPT);
                (PerceptionInbox::new(scenario), poses)
            }),
            commanding: false,
            goal_serial: 0,
        })
    }

    /// The tracks only with the gatekeeper, the scans only with it and a lidar.
    fn takes(&self, topic: &str) -> bool {
        match topic {
            TRACKS => self.tracks.is_some(),
            SCAN => self.scans.is_some(),
            _ => true,
        }
    }

    /// An estimate is queued with its receipt latency; a plan goes to the inbox and the
    /// deadline monitor with its arrival, by the clock, after the start of its sample
    /// ([`Context::arrival_after_ns`]).
    fn hear(&mut self, input: DflInput, latency_ns: u64, context: &impl Context) {
        match input {
            DflInput::Estimate(estimate) => self.queue.push_back((estimate, latency_ns)),
            DflInput::Plan(plan) => {
                let production_ns = plan.solve_ns + plan.injected_delay_ns;
                let arrival_ns = context.arrival_after_ns(
                    self.timing.sample_time_s(plan.sample),
                    production_ns,
                    self.timing.ts_s,
                );
                self.inbox.receive(&plan, arrival_ns);
                self.monitor.on_plan(&plan, arrival_ns);
            }
            DflInput::Tracks(tracks) => {
                if let Some(inbox) = &mut self.tracks {
                    inbox.receive(&tracks);
                }
            }
            DflInput::Scan(scan) => {
                if let Some((inbox, _)) = &mut self.scans {
                    inbox.receive(&scan);
                }
            }
        }
    }

    /// The command for the oldest estimate waiting, with the verdict it gives
    /// ([`DflTask::judged`]); `None` while nothing is waiting, or while the
    /// plan of a new sample is awaited ([`PlanInbox::waits_for`], for
    /// [`PLAN_WAIT_FRACTION`] of the tick). Without an estimate, a brake on the DFL's own
    /// clock when the estimator has been silent for [`SILENT_TICKS`] ticks (then every
    /// tick until estimates come again): the plant must not hold the last command. Never
    /// in lockstep, where time waits for the estimates.
    // Never inlined: tests/instructions.rs counts this step's instructions by its name.
    #[inline(never)]
    fn step(&mut self, context: &impl Context) -> Option<Publish<DflOutput>> {
        let (actuation, verdict) = match self.command_next(context) {
            Some(command) => command,
            None => self.brake_if_silent(context)?,
        };
        Some(Publish::now(DflOutput { verdict, actuation }))
    }

    /// When the task has something to do without an input: the end of a plan wait, or
    /// the next look for a silent estimator. (No scheduled spin for the estimates, unlike
    /// the estimator's for its measurements: on two cores a third spinning process starves
    /// the plant and the estimator, docs/performance.md.)
    fn next(&self) -> Due {
        let plan_wait = (self.queue.front()).and_then(|(e, _)| self.wait_s(e.header.tick));
        let silence = self.watch.next_check().map(|t| self.timing.tick_time_s(t));
        Due::Wait(match (plan_wait, silence) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        })
    }
}

impl DflTask {
    /// The DFL's integrator state zeta, m/s.
    pub fn zeta(&self) -> f64 {
        self.dfl.zeta()
    }

    /// The command for the oldest estimate waiting ([`Task::step`]).
    fn command_next(
        &mut self,
        context: &impl Context,
    ) -> Option<(Actuation, Option<DeadlineVerdict>)> {
        while let Some(&(estimate, latency_ns)) = self.queue.front() {
            let tick = estimate.header.tick;
            if self.watch.is_stale(tick) {
                self.watch.late(tick);
                self.queue.pop_front(); // older than a command already given (braking)
                continue;
            }
            if self.wait_s(tick).is_some_and(|t| !context.is_past(t)) {
                return None;
            }
            self.queue.pop_front();
            if !self.commanding {
                // Not (yet) driving the plant: follow the zeta it is driven with.
                self.dfl.adopt_zeta_of(&estimate);
            }
            self.commanding = context.is_active(tick);
            if let Some(change) = context.goals().due(tick, self.goal_serial) {
                self.goal_serial = change.serial;
                self.dfl.set_goal(change.goal);
            }
            // Orphaned (the supervisor is gone): brake to rest.
            let (mut actuation, verdict) = if context.orphaned() {
                self.brake(tick)
            } else {
                self.command(&estimate, tick)
            };
            actuation.header.input_latency_ns = header_latency(latency_ns);
            self.watch.heard(tick);
            return Some((actuation, verdict));
        }
        None
    }

    /// Until when the command for `tick` waits for its sample's plan, tracks or scan, s: on
    /// the first tick of a sample whose plan ([`PlanInbox::waits_for`]), tracks or scan
    /// ([`PerceptionInbox::waits_for`]) the DFL waits for.
    fn wait_s(&self, tick: u64) -> Option<f64> {
        let sample = self.timing.sample_of(tick);
        let tracks_due = (self.tracks.as_ref()).is_some_and(|t| t.waits_for(tick));
        let scan_due = (self.scans.as_ref()).is_some_and(|(s, _)| s.waits_for(tick));
        let perception_due = tracks_due || scan_due;
        (self.timing.starts_sample(tick) && (self.inbox.waits_for(sample) || perception_due))
            .then(|| (tick as f64 + PLAN_WAIT_FRACTION) * self.timing.dt_s())
    }

    /// A brake for the tick the clock is in, if the estimator has been silent too long
    /// ([`SilenceWatch`]).
    fn brake_if_silent(
        &mut self,
        context: &impl Context,
    ) -> Option<(Actuation, Option<DeadlineVerdict>)> {
        let due = self.watch.next_check()?;
        if !context.has_reached(self.timing.tick_time_s(due)) {
            return None;
        }
        let now = context.now_tick()?.max(due);
        let tick = self.watch.brake_due(now)?;
        Some(self.brake(tick))
    }

    /// The command for `[t_tick, t_tick+1)` from `estimate`, after releasing the plans
    /// usable by now, with its verdict ([`DflTask::judged`]).
    fn command(&mut self, estimate: &Estimate, tick: u64) -> (Actuation, Option<DeadlineVerdict>) {
        let sample = self.timing.sample_of(tick);
        self.inbox.release(sample, &mut self.dfl);
        if let Some(tracks) = &mut self.tracks {
            tracks.release(tick, |t| self.dfl.set_tracks(t));
        }
        if let Some((scans, poses)) = &mut self.scans {
            let [x, y, theta, _] = estimate.state;
            if poses.len() == POSES_KEPT {
                poses.pop_front();
            }
            poses.push_back((tick, [x, y, theta]));
            scans.release(tick, |scan| {
                // Where the robot was when the scan was taken (the oldest kept, if older).
                let taken = scan.taken_tick();
                let pose = (poses.iter().rev())
                    .find(|(t, _)| *t <= taken)
                    .or(poses.front())
                    .map_or([x, y, theta], |(_, pose)| *pose);
                self.dfl
                    .set_scan(scan, protocol::mounted(pose, scan.offset));
            });
        }
        let actuation = self.dfl.step(estimate, tick);
        self.judged(actuation)
    }

    /// `actuation` with the verdict its command gives ([`DeadlineMonitor::commanded`]),
    /// stamped with the command's header, and the misses counted by then.
    fn judged(&mut self, mut actuation: Actuation) -> (Actuation, Option<DeadlineVerdict>) {
        let tick = actuation.header.tick;
        let verdict = (actuation.mode())
            .and_then(|mode| {
                let (sample, first_tick) =
                    (self.timing.sample_of(tick), self.timing.starts_sample(tick));
                self.monitor.commanded(sample, first_tick, mode)
            })
            .map(|verdict| DeadlineVerdict {
                header: actuation.header,
                ..verdict
            });
        actuation.deadline_misses = self.monitor.misses();
        (actuation, verdict)
    }

    /// The fallback brake for `tick` (see [`Dfl::brake`]), with the verdict it gives.
    fn brake(&mut self, tick: u64) -> (Actuation, Option<DeadlineVerdict>) {
        let actuation = self.dfl.brake(tick);
        self.judged(actuation)
    }
}

/// After this many inner ticks without an estimate the DFL brakes on its own (real time:
/// in lockstep time waits for the estimate).
pub const SILENT_TICKS: u64 = 3;

/// Real time: a silent estimator (dead, or stalled) must not leave the plant holding the
/// last command. After [`SILENT_TICKS`] inner ticks without an estimate the DFL brakes on
/// its own clock (the brake needs only zeta), then every tick, until estimates come again.
#[derive(Debug, Clone, Copy, Default)]
pub struct SilenceWatch {
    /// The newest tick commanded, from an estimate or braking alone.
    last_tick: Option<u64>,
    braking_alone: bool,
}

impl SilenceWatch {
    /// Whether an estimate of `tick` comes too late: a command for it was given already.
    pub fn is_stale(&self, tick: u64) -> bool {
        self.last_tick.is_some_and(|last| tick <= last)
    }

    /// An estimate of `tick` came after its command. One of the tick braked last shows an
    /// estimator alive and within a tick, only slower than the brake, which comes at the
    /// tick's start (a slow estimator, `fault.estimator_delay_ms`, after a stall): braking
    /// alone ends, and the next brake waits the silent limit again, so that the next tick
    /// is commanded from its estimate. Braking every tick instead would brake each tick
    /// before its estimate came, for good. An older tick's estimate (an estimator falling
    /// further behind) changes nothing.
    pub fn late(&mut self, tick: u64) {
        if self.last_tick == Some(tick) {
            self.braking_alone = false;
        }
    }

    /// The command for `tick` was given from an estimate.
    pub fn heard(&mut self, tick: u64) {
        self.last_tick = Some(tick);
        self.braking_alone = false;
    }

    fn silent_ticks(&self) -> u64 {
        if self.braking_alone { 1 } else { SILENT_TICKS }
    }

    /// With the clock in tick `now_tick`: the tick to brake at now, if the estimator has
    /// been silent for too long (never before the first estimate).
    pub fn brake_due(&mut self, now_tick: u64) -> Option<u64> {
        let last = self.last_tick?;
        (now_tick >= last + self.silent_ticks()).then(|| {
            self.last_tick = Some(now_tick);
            self.braking_alone = true;
            now_tick
        })
    }

    /// The tick at which to look again for silence.
    pub fn next_check(&self) -> Option<u64> {
        self.last_tick.map(|last| last + self.silent_ticks())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tracks_of_a_samples_start_are_waited_for_and_later_ones_wait_for_the_next_sample() {
        // Ten inner ticks a sample, a measurement every five.
        let scenario = protocol::Scenario::default()
            .with_overrides(&["perception.period_s=0.025".into()])
            .and_then(|s| s.validated("test"))
            .unwrap();
        let mut inbox = TrackInbox::new(&scenario);
        let heard = |tick: u64| Tracks {
            header: Header {
                tick,
                ..Header::default()
            },
            ..Tracks::default()
        };
        let released = |inbox: &mut TrackInbox, tick: u64| {
            let mut ticks = Vec::new();
            inbox.release(tick, |t| ticks.push(t.header.tick));
            ticks
        };
        assert!(inbox.waits_for(0), "no tracks yet");
        inbox.receive(&heard(0));
        assert!(!inbox.waits_for(0));
        inbox.receive(&heard(5));
        assert_eq!(released(&mut inbox, 3), vec![0]);
        assert_eq!(
            released(&mut inbox, 9),
            Vec::<u64>::new(),
            "tick 5: next sample"
        );
        assert!(inbox.waits_for(10), "the tracks of tick 10 not heard");
        inbox.receive(&heard(10));
        inbox.receive(&heard(10));
        assert!(!inbox.waits_for(19));
        assert_eq!(released(&mut inbox, 10), vec![5, 10], "each once, in order");
    }

    #[test]
    fn a_silent_estimator_is_braked_for_after_silent_ticks_then_every_tick() {
        let mut watch = SilenceWatch::default();
        assert_eq!(
            watch.brake_due(100),
            None,
            "no estimate yet: nothing to hold"
        );
        watch.heard(10);
        assert!(watch.is_stale(10) && !watch.is_stale(11));
        assert_eq!(watch.next_check(), Some(10 + SILENT_TICKS));
        assert_eq!(watch.brake_due(10 + SILENT_TICKS - 1), None);
        assert_eq!(watch.brake_due(10 + SILENT_TICKS), Some(13));
        assert_eq!(watch.next_check(), Some(14), "braking alone: every tick");
        assert_eq!(watch.brake_due(13), None);
        assert_eq!(watch.brake_due(14), Some(14));
        assert!(
            watch.is_stale(14),
            "an estimate of a braked tick is too late"
        );
        watch.heard(15);
        assert_eq!(
            watch.brake_due(16),
            None,
            "estimates again: back to the silent limit"
        );
        assert_eq!(watch.next_check(), Some(15 + SILENT_TICKS));
    }

    #[test]
    fn a_late_estimate_of_the_tick_braked_last_ends_braking_alone_and_an_older_one_does_not() {
        let mut watch = SilenceWatch::default();
        watch.heard(10);
        assert_eq!(watch.brake_due(13), Some(13));
        assert_eq!(watch.brake_due(14), Some(14));
        // An estimator falling further behind: tick 12's estimate, after tick 14's brake.
        watch.late(12);
        assert_eq!(watch.next_check(), Some(15), "still braking every tick");
        assert_eq!(watch.brake_due(15), Some(15));
        // Tick 15's estimate within tick 15, after its brake: the estimator is alive.
        assert!(watch.is_stale(15));
        watch.late(15);
        assert_eq!(watch.next_check(), Some(15 + SILENT_TICKS));
        assert_eq!(watch.brake_due(16), None, "tick 16 waits for its estimate");
        assert!(!watch.is_stale(16));
        watch.heard(16);
        assert_eq!(watch.next_check(), Some(16 + SILENT_TICKS));
    }
}
