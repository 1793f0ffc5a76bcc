//! The MPC role as a task ([`protocol::task`]): plan(k) from the estimate of sample k's
//! first tick, with the scenario's injected faults.
//!
//! With a planner (`planner.kind = "route"`) plan(k) follows the newest route of an
//! earlier sample, route(k - 1) in a whole run (the planner is never between the estimate
//! and the plan): the task waits for route(k - 1) until the time of sample k is past (in
//! lockstep: until it comes; a restarted planner answers the newest estimate). Without
//! any route (the first sample, a planner not heard yet) it drives to the goal. When it
//! has fallen behind, a sample whose successor's time is past is not solved: only the
//! newest is.
//!
//! With a tracker (an obstacle moves, or `perception.kind = "track"`) plan(k) keeps clear
//! of the discs predicted by the newest tracks of a perception tick at or before sample
//! k's: the task waits for those until half an inner tick after sample k's time (in
//! lockstep: until they come). Before any track has come there is no plan: the DFL's
//! fallback holds the robot (it cannot know where the moving obstacles are).

use crate::Mpc;
use protocol::samples::SampleQueue;
use protocol::task::{Cancel, Context, Due, GoalChange, Publish, Task, TaskError, header_latency};
use protocol::{Estimate, FaultConfig, Header, Plan, Role, Route, Tracks, Validated};
use std::collections::VecDeque;

/// What the MPC takes: the estimator's estimates (periodic: one a sample matters) and,
/// with a planner, its routes.
// By value, as the messages come (boxing would allocate per sample).
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, Copy)]
pub enum MpcInput {
    Estimate(Estimate),
    Route(Route),
    Tracks(Tracks),
}
protocol::task_input!(MpcInput: Estimate, Route, Tracks);

/// A warm-up steps the next sample dry when the last step took at most this share of an
/// inner tick (half the earliest a warm-up starts, half a tick before the sample's due
/// time: a dry step as long could run into the sample), else it solves the last program
/// again ([`Mpc::warm_up`]).
pub const DRY_STEP_MAX_TICKS: f64 = 0.25;

/// The MPC with the boundary estimates and the routes it has heard.
pub struct MpcTask {
    mpc: Mpc,
    faults: FaultConfig,
    follows_route: bool,
    /// The longest last step after which a warm-up steps dry, ns ([`DRY_STEP_MAX_TICKS`]).
    dry_step_max_ns: u64,
    /// Boundary estimates of samples not solved yet, with their receipt latency, ns.
    samples: SampleQueue<u64>,
    /// The newest routes heard, oldest first (a few samples' worth).
    routes: VecDeque<Route>,
    /// Inner ticks between two perception ticks; `None`: no tracker runs.
    perception_ticks: Option<u64>,
    /// The tick of the newest tracks heard.
    tracks_tick: Option<u64>,
    /// How long after a sample's time its tracks are waited for, s: half an inner tick,
    /// and a quarter sample for the first tracks (a tracker that has just started, on a
    /// machine where a fleet's every process starts at once, is slow to its first).
    tracks_grace_s: f64,
    first_tracks_grace_s: f64,
    /// The run's scenario, to build the MPC anew for a goal set while the run drives.
    scenario: Validated,
    /// The serial of that goal (0: none, `robot.goal`).
    goal_serial: u32,
    /// The newest tracks heard, for an MPC built anew.
    newest_tracks: Option<Tracks>,
    /// The first sample whose route leads to the goal (routes planned before it lead to
    /// an old one).
    first_route_sample: u64,
    /// Whether the plans' timeline runs behind the clock
    /// ([`protocol::Scenario::command_lead_s`]): then each sample is planned from its
    /// estimate predicted to when the commands in flight have taken effect
    /// ([`protocol::Estimate::ahead`]).
    plans_ahead: bool,
    /// In a fleet, the rule that breaks deadlocks ([`crate::give_way`]).
    give_way: Option<crate::give_way::GiveWay>,
}

impl Task for MpcTask {
    const ROLE: Role = Role::Mpc;
    type Input = MpcInput;
    type Output = Plan;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<MpcTask, TaskError> {
        let mpc = Mpc::new(scenario).map_err(|e| TaskError::setup(Role::Mpc, e))?;
        Ok(MpcTask {
            mpc,
            faults: scenario.fault.clone(),
            follows_route: scenario.plans_routes(),
            dry_step_max_ns: (DRY_STEP_MAX_TICKS * scenario.timing.dt_s() * 1e9) as u64,
            samples: SampleQueue::new(&scenario.timing),
            routes: VecDeque::with_capacity(4),
            perception_ticks: scenario
                .roles()
                .any(|r| r == Role::Tracker)
                .then(|| scenario.perception_ticks()),
            tracks_tick: None,
            tracks_grace_s: 0.5 * scenario.timing.dt_s(),
            first_tracks_grace_s: 0.25 * scenario.timing.ts_s,
            scenario: scenario.clone(),
            goal_serial: 0,
            newest_tracks: None,
            first_route_sample: 0,
            plans_ahead: scenario.command_lead_s() > 0.0,
            give_way: crate::give_way::GiveWay::of(scenario),
        })
    }

    /// Only the estimates that start a sample are stepped on.
    fn woken_at_sample_starts(&self, topic: &str) -> bool {
        topic == protocol::topics::ESTIMATE
    }

    /// An estimate is kept if it starts a sample not solved yet (a replay repeats one that
    /// was), with its receipt latency; routes are kept a few samples' worth.
    fn hear(&mut self, input: MpcInput, latency_ns: u64, _context: &impl Context) {
        match input {
            MpcInput::Estimate(estimate) => self.samples.hear(estimate, latency_ns),
            MpcInput::Route(route) => {
                if self.routes.len() == self.routes.capacity() {
                    self.routes.pop_front();
                }
                self.routes.push_back(route);
            }
            MpcInput::Tracks(tracks) => {
                if self.tracks_tick.is_none_or(|t| tracks.header.tick > t) {
                    self.tracks_tick = Some(tracks.header.tick);
                    self.mpc.set_tracks(&tracks);
                    self.newest_tracks = Some(tracks);
                }
            }
        }
    }

    /// Only every M-th estimate matters: rather than waking for each one (and taking a
    /// core from the DFL), the next sample's is expected.
    fn next(&self) -> Due {
        Due::Expect(Some(self.samples.next_due_s()))
    }

    /// Asleep for most of `Ts` in real time, the step would start with cold caches.
    fn warms_up(&self) -> bool {
        true
    }

    /// Warms the next step's memory before the next sample ([`Mpc::warm_up`]); changes no
    /// plan.
    fn warm_up(&mut self, cancel: &Cancel) {
        self.mpc.warm_up(self.dry_step_max_ns, cancel);
    }

    /// The next plan, if a boundary estimate is waiting and what it needs has come; the
    /// plan's `injected_delay_ns` (`fault.mpc_delay_*`) is how long it is held.
    // Never inlined: tests/instructions.rs counts this step's instructions by its name.
    #[inline(never)]
    fn step(&mut self, context: &impl Context) -> Option<Publish<Plan>> {
        let (sample, estimate, latency_ns) = self.samples.oldest(context)?;
        let route_due = self.follows_route
            && sample > 0
            && self.routes.back().is_none_or(|r| r.sample + 1 < sample);
        if route_due && !context.is_past(estimate.header.time_s) {
            return None; // route(k - 1) is on its way
        }
        if let Some(period) = self.perception_ticks {
            let tick = estimate.header.tick;
            let due = tick - tick % period;
            if self.tracks_tick.is_none_or(|t| t < due) {
                let grace_s = match self.tracks_tick {
                    Some(_) => self.tracks_grace_s,
                    None => self.first_tracks_grace_s,
                };
                if !context.is_past(estimate.header.time_s + grace_s) {
                    return None; // the tracks of `due` are on their way
                }
                if self.tracks_tick.is_none() {
                    self.samples.answered();
                    return None; // no track yet: no plan
                }
            }
        }
        self.samples.answered();
        // (A step that builds the MPC anew counts the build in its time.)
        let started_ns = context.monotonic_ns();
        if let Some(change) = context.goals().due(estimate.header.tick, self.goal_serial) {
            self.retarget(change);
        }
        let first_route = self.first_route_sample;
        let route =
            (self.routes.iter().rev()).find(|r| r.sample < sample && r.sample >= first_route);
        let x_bar = if self.plans_ahead {
            estimate.ahead
        } else {
            estimate.state
        };
        let detour = self.give_way.as_mut().and_then(|rule| {
            let motion = ([x_bar[0], x_bar[1]], x_bar[3]);
            let goal = self.scenario.robot.goal.position;
            let tracks = self.newest_tracks.as_ref();
            rule.detour(estimate.header.time_s, motion, goal, route, tracks)
        });
        let route = detour.as_ref().map(|(r, _)| r).or(route);
        let mut plan = (self.mpc).step_on_route(sample, x_bar, estimate.position_sigma(), route);
        plan.gives_way = detour.map_or(0, |(_, peer)| peer + 1);
        plan.solve_ns = context.monotonic_ns().saturating_sub(started_ns);
        self.mpc.took(plan.solve_ns);
        self.mpc.inject_faults(&mut plan, &self.faults);
        plan.header = Header {
            tick: estimate.header.tick,
            time_s: estimate.header.time_s,
            input_latency_ns: header_latency(latency_ns),
            ..Header::default()
        };
        Some(Publish {
            output: plan,
            hold_ns: plan.injected_delay_ns,
        })
    }
}

impl MpcTask {
    /// Drives to the goal of `change`: the MPC built anew for it (its program is relative
    /// to the goal, [`crate::linear`]), with the newest tracks; routes of samples before
    /// the goal's first (which the planner planned to the old goal) are not followed.
    /// (A scenario valid with one goal builds with another its checks accepted: should it
    /// not, the MPC goes on to the old goal.)
    fn retarget(&mut self, change: GoalChange) {
        self.goal_serial = change.serial;
        self.first_route_sample = self.scenario.timing.sample_of(change.from_tick);
        self.scenario = self.scenario.with_goal(change.goal);
        if let Ok(mut mpc) = Mpc::new(&self.scenario) {
            if let Some(tracks) = &self.newest_tracks {
                mpc.set_tracks(tracks);
            }
            self.mpc = mpc;
        }
    }
}
