//! The in-process executor: every role's task ([`protocol::task::Task`]) stepped in one
//! process on simulated time standing at the current tick, whatever the roles.
//! `scmpc run --in-process`, `sweep`, `figures`, the allocation test and the step
//! benchmarks all step this one loop; the role processes step the same tasks
//! ([`runtime::serve`]).
//!
//! Per inner tick `j` (time `t_j = j Ts / M`), each running role in [`Role::ALL`] order is
//! stepped until it has nothing more to give, and each message it gives is handed at once
//! to every task that takes its topic ([`protocol::graph`]); a message on a topic its
//! role does not declare as an output ends the run ([`Ended::Undeclared`]). That order is the
//! order of the data within a tick: the plant's measurement of tick `j` (after integrating
//! the command of tick `j - 1`), the estimate, on a sample boundary the MPC's plan(k), the
//! DFL's command for `[t_j, t_j+1)` with its verdict on the previous sample, and the
//! planner's route(k), which the MPC follows from the next sample on (so the planner is
//! never on the path from the estimate to the plan). A command reaches the plant and the
//! estimator for the next tick. A plan whose production time exceeds `Ts` reaches the DFL
//! `ceil(production / Ts)` samples late, as it would in real time
//! ([`SimulatedTime`](protocol::task::SimulatedTime)).
//!
//! What a process executor adds, this one does as its supervision would: a message its
//! consumers would refuse ([`protocol::Message::content_rejection`]) is dropped and its
//! producer restarted as the scenario's restart policy allows (a new task, with the next
//! producer epoch, that hears the newest sample of each of its inputs again), so that
//! every injected fault gives the same run here as over iceoryx2 in lockstep.

use crate::roles;
use protocol::graph::Graph;
use protocol::task::{GoalChange, Goals, Outputs, SimulatedTime, Task};
use protocol::{
    Actuation, Data, DeadlineVerdict, Estimate, GroundTruth, Plan, RestartPolicy, Role, Route,
    Tracks, Validated,
};

/// One inner tick of the closed loop: what every role produced.
#[derive(Debug, Clone)]
pub struct Tick {
    /// The plant's pose at the start of the tick.
    pub truth: GroundTruth,
    pub estimate: Estimate,
    /// The plan solved at this tick (sample boundaries only).
    pub plan: Option<Plan>,
    /// The planner's route of this tick (sample boundaries of runs with a planner).
    pub route: Option<Route>,
    /// The tracker's tracks of this tick (perception ticks of runs with a tracker).
    pub tracks: Option<Tracks>,
    /// The deadline monitor's verdict on the sample this tick starts (boundaries only).
    pub verdict: Option<DeadlineVerdict>,
    /// The DFL's command for the tick, with the deadline misses so far.
    pub actuation: Actuation,
    /// The role restarted at this tick, with the topic of its message that was refused.
    pub restarted: Option<(Role, &'static str)>,
    /// The tick's messages of topics the record has no place of its own for and records
    /// as [`Data`] ([`protocol::Message::RECORDED`]), in the order they were given.
    pub recorded: Vec<Data>,
}

/// Why the loop ended before its last tick.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Ended {
    /// A message of `role` was refused and the restart policy allows no new process.
    #[error("{topic} of the {} refused, no restart left", role.as_str())]
    Aborted { role: Role, topic: &'static str },
    /// A tick ended without a message every tick has (the tasks disagree with the
    /// executor: a defect).
    #[error("tick {tick} ended without a {topic}")]
    Stalled { tick: u64, topic: &'static str },
    /// A task gave a message on a topic its role does not declare as an output (a defect
    /// of the task or of the declaration).
    #[error("the {} gave a message on `{topic}`, which its declaration does not name", role.as_str())]
    Undeclared { role: Role, topic: &'static str },
}

/// A task as this executor steps it, whatever its role.
pub trait Stepped {
    fn role(&self) -> Role;
    /// Whether it takes messages of `topic`, one of its role's inputs ([`Task::takes`]).
    fn takes(&self, topic: &str) -> bool;
    /// Whether its input type has a variant for `data` (what it could hear at all).
    fn accepts(&self, data: Data) -> bool;
    fn hear(&mut self, data: Data, time: &SimulatedTime);
    /// Hands it another robot's sample if it takes that topic from the others
    /// ([`Task::peer_topics`]).
    fn hear_peer(&mut self, data: &Data);
    /// Steps the task once; what it gives is pushed to `given` (false: nothing).
    fn step(&mut self, time: &SimulatedTime, given: &mut Vec<Data>) -> bool;
}

impl<T: Task> Stepped for T {
    fn role(&self) -> Role {
        T::ROLE
    }

    fn takes(&self, topic: &str) -> bool {
        Task::takes(self, topic)
    }

    fn accepts(&self, data: Data) -> bool {
        T::Input::try_from(data).is_ok()
    }

    fn hear(&mut self, data: Data, time: &SimulatedTime) {
        if let Ok(input) = T::Input::try_from(data) {
            Task::hear(self, input, 0, time);
        }
    }

    fn hear_peer(&mut self, data: &Data) {
        if self.peer_topics().contains(&data.topic()) {
            Task::hear_peer(self, data);
        }
    }

    fn step(&mut self, time: &SimulatedTime, given: &mut Vec<Data>) -> bool {
        match Task::step(self, time) {
            Some(publish) => {
                publish.output.each(|data| given.push(data));
                true
            }
            None => false,
        }
    }
}

/// What a task is wired to in a run: the topics it takes (its role's declared inputs whose
/// producer runs, as the task takes them) and its role's outputs.
struct Wiring {
    inputs: Vec<&'static str>,
    outputs: &'static [&'static str],
}

impl Wiring {
    fn of(task: &dyn Stepped, graph: &Graph) -> Wiring {
        let role = task.role();
        Wiring {
            inputs: graph.inputs_of(role).filter(|t| task.takes(t)).collect(),
            outputs: graph.declaration(role).map_or(&[][..], |d| d.outputs),
        }
    }
}

/// The tasks of one scenario, stepped in lockstep.
pub struct ClosedLoop {
    scenario: Validated,
    /// The running roles' tasks, in [`Role::ALL`] order.
    tasks: Vec<Box<dyn Stepped>>,
    /// The topics each task takes in this run, and those its role publishes.
    wiring: Vec<Wiring>,
    graph: Graph,
    /// Restarts so far, by role (the producer epoch of the one running).
    restarts: [u32; Role::COUNT],
    /// The newest message of each data topic, which a restarted task hears again.
    newest: Vec<Data>,
    /// What the tasks gave in this tick, in order.
    given: Vec<Data>,
    tick: u64,
    ticks: u64,
    /// The goals set while the run drives ([`protocol::task::Context::goals`]).
    goals: Goals,
}

impl ClosedLoop {
    /// The tasks of `scenario` at their initial states.
    pub fn new(scenario: &Validated) -> Result<Self, protocol::task::TaskError> {
        let tasks = scenario
            .roles()
            .map(|role| roles::in_process(role, scenario, 0))
            .collect::<Result<Vec<_>, _>>()?;
        let graph = Graph::of(scenario);
        let wiring = tasks
            .iter()
            .map(|t| Wiring::of(t.as_ref(), &graph))
            .collect();
        Ok(Self {
            scenario: scenario.clone(),
            tasks,
            wiring,
            graph,
            restarts: [0; Role::COUNT],
            newest: Vec::with_capacity(protocol::graph::TOPICS.len()),
            given: Vec::with_capacity(16),
            tick: 0,
            ticks: scenario.tick_count(),
            goals: Goals::default(),
        })
    }

    /// Inner ticks per sample.
    pub fn inner_steps(&self) -> usize {
        self.scenario.timing.inner_steps
    }

    /// Tells every task of `change` from the next tick on.
    pub fn set_goal(&mut self, change: GoalChange) {
        self.goals.set(change);
    }

    /// Hands `data`, a sample of another robot of a fleet (stamped with its id,
    /// [`protocol::Header::robot`]), to every task that takes it from the others
    /// ([`protocol::task::Task::peer_topics`]), before the next tick.
    pub fn hear_peer(&mut self, data: &Data) {
        for task in &mut self.tasks {
            task.hear_peer(data);
        }
    }

    /// The tick the next [`step`](Self::step) runs.
    pub fn tick(&self) -> u64 {
        self.tick
    }

    /// Whether every tick of the run's duration has been stepped.
    pub fn is_done(&self) -> bool {
        self.tick >= self.ticks
    }

    /// One inner tick: every role's pass in order.
    pub fn step(&mut self) -> Result<Tick, Ended> {
        self.step_each(|_, pass| pass())
    }

    /// [`step`](Self::step), each role's pass (its steps and the hand-over of what it
    /// gave) run through `around` (the allocation test counts allocations role by role).
    pub fn step_each(
        &mut self,
        mut around: impl FnMut(Role, &mut dyn FnMut()),
    ) -> Result<Tick, Ended> {
        let time = SimulatedTime::at(self.tick, self.scenario.timing.dt_s()).with_goals(self.goals);
        self.given.clear();
        let mut restarted = None;
        for i in 0..self.tasks.len() {
            let role = self.tasks[i].role();
            let mut refused = Ok(None);
            around(role, &mut || refused = self.pass(i, &time));
            while let Some(topic) = std::mem::replace(&mut refused, Ok(None))? {
                self.restart(i, topic)?;
                restarted = Some((role, topic));
                around(role, &mut || refused = self.pass(i, &time));
            }
        }
        self.tick += 1;
        self.collect(restarted)
    }

    /// After the last tick: the plant's truth at the end of the run (its pose after the
    /// last command).
    pub fn final_truth(&mut self) -> Option<GroundTruth> {
        let time = SimulatedTime::at(self.tick, self.scenario.timing.dt_s());
        self.given.clear();
        let plant = self.tasks.iter().position(|t| t.role() == Role::Plant)?;
        self.tasks[plant].step(&time, &mut self.given);
        self.given.iter().find_map(|d| match d {
            Data::Truth(truth) => Some(*truth),
            _ => None,
        })
    }

    /// Steps task `i` until it gives nothing more, handing each message to the tasks that
    /// take its topic; the topic of a message its consumers would refuse (dropped), if one
    /// came.
    fn pass(&mut self, i: usize, time: &SimulatedTime) -> Result<Option<&'static str>, Ended> {
        loop {
            let from = self.given.len();
            if !self.tasks[i].step(time, &mut self.given) {
                return Ok(None);
            }
            for k in from..self.given.len() {
                let data = self.given[k];
                if !self.wiring[i].outputs.contains(&data.topic()) {
                    let role = self.tasks[i].role();
                    return Err(Ended::Undeclared {
                        role,
                        topic: data.topic(),
                    });
                }
                if data.content_rejection().is_some() {
                    self.given.truncate(k);
                    return Ok(Some(data.topic()));
                }
                self.hand_over(data, time);
            }
        }
    }

    /// Hands `data` to every task that takes its topic, and keeps it as the newest.
    fn hand_over(&mut self, data: Data, time: &SimulatedTime) {
        match self.newest.iter_mut().find(|d| d.topic() == data.topic()) {
            Some(newest) => *newest = data,
            None => self.newest.push(data),
        }
        for (task, wiring) in self.tasks.iter_mut().zip(&self.wiring) {
            if wiring.inputs.contains(&data.topic()) {
                task.hear(data, time);
            }
        }
    }

    /// Replaces task `i`, whose message of `topic` was refused, by a new one if the
    /// restart policy allows: it hears the newest message of each of its inputs.
    fn restart(&mut self, i: usize, topic: &'static str) -> Result<(), Ended> {
        let role = self.tasks[i].role();
        let supervision = &self.scenario.supervision;
        let restarts = &mut self.restarts[role as usize];
        if supervision.restart != RestartPolicy::Always || *restarts >= supervision.max_restarts {
            return Err(Ended::Aborted { role, topic });
        }
        *restarts += 1;
        let task = roles::in_process(role, &self.scenario, *restarts)
            .map_err(|_| Ended::Aborted { role, topic })?;
        self.wiring[i] = Wiring::of(task.as_ref(), &self.graph);
        self.tasks[i] = task;
        let time = SimulatedTime::at(self.tick, self.scenario.timing.dt_s());
        let task = &mut self.tasks[i];
        for data in &self.newest {
            if self.wiring[i].inputs.contains(&data.topic()) {
                task.hear(*data, &time);
            }
        }
        Ok(())
    }

    /// The tick's record from what the tasks gave.
    fn collect(&self, restarted: Option<(Role, &'static str)>) -> Result<Tick, Ended> {
        let (mut truth, mut estimate, mut actuation) = (None, None, None);
        let (mut plan, mut route, mut verdict, mut tracks) = (None, None, None, None);
        let mut recorded = Vec::new();
        for data in &self.given {
            match *data {
                Data::Truth(m) => truth = Some(m),
                Data::Estimate(m) => estimate = Some(m),
                Data::Actuation(m) => actuation = Some(m),
                Data::Plan(m) => plan = Some(m),
                Data::Route(m) => route = Some(m),
                Data::Deadline(m) => verdict = Some(m),
                Data::Tracks(m) => tracks = Some(m),
                other if !Data::recorded_names(other.topic()).is_empty() => recorded.push(other),
                _ => {}
            }
        }
        let tick = self.tick - 1;
        let missing = |topic| Ended::Stalled { tick, topic };
        Ok(Tick {
            truth: truth.ok_or_else(|| missing(protocol::topics::TRUTH))?,
            estimate: estimate.ok_or_else(|| missing(protocol::topics::ESTIMATE))?,
            actuation: actuation.ok_or_else(|| missing(protocol::topics::ACTUATION))?,
            plan,
            route,
            tracks,
            verdict,
            restarted,
            recorded,
        })
    }
}
