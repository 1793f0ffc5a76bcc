//! The plant role as a task ([`protocol::task`]): tick `j` is due at `t_j`; it integrates
//! the actuation of tick `j - 1` over `[t_(j-1), t_j)` and outputs the truth and the
//! measurement of tick `j`.
//!
//! Like a real base's command watchdog, the plant brakes on its own once its newest
//! command is `plant.command_timeout_s` old: a DFL on a host that is lost can no longer
//! brake it ([`watchdog_command`]). When commands come again it does not jump to them:
//! it ramps its forward speed to theirs at the same deceleration ([`resumed_command`]),
//! as a DFL that braked on its own clock meanwhile commands a speed the base no longer
//! has (docs/hosts.md, "A slow or broken link").

use crate::Plant;
pub use protocol::task::PlantOutput;
use protocol::task::{Context, Due, Publish, Task, TaskError, header_latency, keep_newest};
use protocol::{Actuation, GroundTruth, Header, Measurement, Role, Timing, Validated};

/// What the plant takes: the DFL's commands.
#[derive(Debug, Clone, Copy)]
pub enum PlantInput {
    Actuation(Actuation),
}
protocol::task_input!(PlantInput: Actuation);

/// The plant, the actuation it holds, and the tick it makes next.
pub struct PlantTask {
    plant: Plant,
    timing: Timing,
    /// The newest actuation heard.
    held: Option<Actuation>,
    /// The command `[u1 m/s, u2 rad/s]` applied over the last tick, after saturation.
    applied: [f64; 2],
    /// How many ticks the held command is applied beyond its own tick before the plant
    /// brakes on its own (`plant.command_timeout_s` in whole inner ticks).
    timeout_ticks: u64,
    /// The watchdog's deceleration, m/s^2: the DFL's brake's (`Scenario::brake_decel`).
    brake_decel: f64,
    /// Since the watchdog braked, until the base's forward speed has come to the resumed
    /// commands' ([`resumed_command`]).
    resuming: bool,
    /// The tick to output next.
    tick: u64,
}

impl Task for PlantTask {
    const ROLE: Role = Role::Plant;
    type Input = PlantInput;
    type Output = PlantOutput;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<PlantTask, TaskError> {
        Ok(PlantTask {
            plant: Plant::new(scenario),
            timing: scenario.timing.clone(),
            held: None,
            applied: [0.0; 2],
            timeout_ticks: (scenario.plant.command_timeout_s / scenario.timing.dt_s()).round()
                as u64,
            brake_decel: scenario.brake_decel(),
            resuming: false,
            tick: 0,
        })
    }

    /// An actuation heard; the newest is held until a newer one comes.
    fn hear(&mut self, input: PlantInput, _latency_ns: u64, _context: &impl Context) {
        let PlantInput::Actuation(actuation) = input;
        keep_newest(&mut self.held, actuation);
    }

    /// The next tick is due at its time.
    fn next(&self) -> Due {
        Due::At(self.timing.tick_time_s(self.tick))
    }

    /// The next tick, once the clock has reached it and the actuation of the tick before
    /// has been heard or is too late (then the newest held is applied, or none: the robot
    /// stands still; held beyond `plant.command_timeout_s`, the watchdog brakes).
    fn step(&mut self, context: &impl Context) -> Option<Publish<PlantOutput>> {
        let tick = self.tick;
        let due_s = self.timing.tick_time_s(tick);
        let previous_heard = self.held.is_some_and(|a| a.header.tick + 1 >= tick);
        if !context.has_reached(due_s) || !(tick == 0 || previous_heard || context.is_past(due_s)) {
            return None;
        }
        let mut watchdog = Watchdog::Off;
        if tick > 0 {
            let (dt_s, speeds) = (self.timing.dt_s(), self.plant.speeds());
            let [u1, u2] = match self.held {
                None => [0.0; 2],
                // The held command was for tick `k`, over `[t_k, t_(k+1))`.
                Some(a) if (tick - 1).saturating_sub(a.header.tick) > self.timeout_ticks => {
                    (watchdog, self.resuming) = (Watchdog::Braking, true);
                    watchdog_command(speeds, self.brake_decel, dt_s)
                }
                Some(a) if self.resuming => {
                    let command = [a.u1, a.u2];
                    let ramped = resumed_command(speeds, command, self.brake_decel, dt_s);
                    self.resuming = ramped != command;
                    if self.resuming {
                        watchdog = Watchdog::Resuming;
                    }
                    ramped
                }
                Some(a) => [a.u1, a.u2],
            };
            self.applied = self.plant.step(u1, u2, dt_s);
        }
        self.tick += 1;
        let header = Header {
            tick,
            time_s: due_s,
            input_latency_ns: header_latency(context.clock_latency_ns()),
            ..Header::default()
        };
        let truth = GroundTruth {
            header,
            pose: self.plant.pose(),
            applied: self.applied,
            watchdog: watchdog as u32,
            reserved: 0,
        };
        let measurement = Measurement {
            header,
            y: self.plant.measure(),
            odometry: self.plant.speeds(),
        };
        Some(Publish::now(PlantOutput { truth, measurement }))
    }
}

/// The command of a base whose commands have stopped (its watchdog): no turning, and its
/// forward speed now (`speeds`, `[u1 m/s, u2 rad/s]`) brought towards 0 by `brake_decel`
/// (m/s^2) over the tick of `dt_s`, straight along the heading as the DFL's brake
/// brakes, within the input box the other robots of a fleet allow it.
pub fn watchdog_command(speeds: [f64; 2], brake_decel: f64, dt_s: f64) -> [f64; 2] {
    let speed = speeds[0];
    let slower = (speed.abs() - brake_decel * dt_s).max(0.0);
    [slower.copysign(speed), 0.0]
}

/// [`GroundTruth::watchdog`]: what the base's own watchdog did over a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Watchdog {
    /// The tick's command applied as it came.
    Off = 0,
    /// Braking: no command for `plant.command_timeout_s` ([`watchdog_command`]).
    Braking = 1,
    /// Ramping to the resumed commands' forward speed ([`resumed_command`]).
    Resuming = 2,
}

/// The command a base applies when commands come again after its watchdog braked: the
/// `command`'s turn rate (rad/s), and a forward speed brought from the base's now
/// (`speeds`, `[u1 m/s, u2 rad/s]`) towards the command's by at most `brake_decel` (m/s^2)
/// over the tick of `dt_s`. The DFL that sends it may have braked on its own meanwhile
/// (its estimates stopped too) or not: either way the base does not jump to a speed it
/// does not have, and stays within the input box the other robots of a fleet allow it.
/// It is the command itself once the base's speed is within a tick of it.
pub fn resumed_command(
    speeds: [f64; 2],
    command: [f64; 2],
    brake_decel: f64,
    dt_s: f64,
) -> [f64; 2] {
    let step = brake_decel * dt_s;
    let forward = command[0].clamp(speeds[0] - step, speeds[0] + step);
    [forward, command[1]]
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Scenario;
    use protocol::task::SimulatedTime;

    /// Steps the plant through tick `tick`, its clock a tick beyond (so a missing actuation
    /// is too late): the truth it publishes.
    fn truth_through(task: &mut PlantTask, tick: u64) -> GroundTruth {
        let dt_s = task.timing.dt_s();
        let stepped = task.step(&SimulatedTime::at(tick + 1, dt_s));
        stepped.expect("a tick past steps").output.truth
    }

    #[test]
    fn a_plant_whose_commands_stop_holds_the_last_until_its_timeout_then_brakes_to_rest() {
        let mut scenario = Scenario::paper();
        scenario.plant.command_timeout_s = 0.1;
        let scenario = scenario.validated("test").expect("valid");
        let dt_s = scenario.timing.dt_s();
        let mut task = PlantTask::new(&scenario, 0, ()).expect("plant");
        let command = Actuation {
            u1: 0.6,
            u2: 0.4,
            ..Actuation::default()
        };
        task.hear(
            PlantInput::Actuation(command),
            0,
            &SimulatedTime::at(0, dt_s),
        );
        truth_through(&mut task, 0);
        let holding = (0.1 / dt_s).round() as u64;
        for tick in 1..=holding + 1 {
            let truth = truth_through(&mut task, tick);
            assert_eq!(
                (truth.applied, truth.watchdog),
                ([0.6, 0.4], 0),
                "tick {tick} holds"
            );
        }
        let decel = scenario.brake_decel();
        let braked = truth_through(&mut task, holding + 2);
        assert_eq!(braked.watchdog, 1, "the watchdog brakes");
        assert!(
            (braked.applied[0] - (0.6 - decel * dt_s)).abs() < 1e-12,
            "{braked:?}"
        );
        assert_eq!(braked.applied[1], 0.0, "the watchdog does not turn");
        let mut tick = holding + 2;
        while task.plant.speeds()[0] > 0.0 {
            tick += 1;
            assert_eq!(truth_through(&mut task, tick).watchdog, 1);
        }
        let stop_s = (tick - holding - 1) as f64 * dt_s;
        assert!(
            (stop_s - 0.6 / decel).abs() <= dt_s,
            "stopped after {stop_s} s"
        );
    }

    #[test]
    fn commands_that_come_again_after_the_watchdog_braked_are_ramped_to_not_jumped_to() {
        let mut scenario = Scenario::paper();
        scenario.plant.command_timeout_s = 0.1;
        let scenario = scenario.validated("test").expect("valid");
        let (dt_s, decel) = (scenario.timing.dt_s(), scenario.brake_decel());
        let mut task = PlantTask::new(&scenario, 0, ()).expect("plant");
        let command = |tick: u64, u1: f64, u2: f64| {
            let header = Header {
                tick,
                ..Header::default()
            };
            let actuation = Actuation {
                header,
                u1,
                u2,
                ..Actuation::default()
            };
            PlantInput::Actuation(actuation)
        };
        let hear = |task: &mut PlantTask, input| task.hear(input, 0, &SimulatedTime::at(0, dt_s));
        hear(&mut task, command(0, 0.6, 0.0));
        let braking_from = (0.1 / dt_s).round() as u64 + 2;
        for tick in 0..braking_from + 5 {
            truth_through(&mut task, tick);
        }
        let speed = task.plant.speeds()[0];
        assert!(speed < 0.6 && speed > 0.3, "braked to {speed} m/s");
        // A DFL that braked to rest on its own meanwhile: the base slows to it at the
        // watchdog's deceleration, turning as told.
        let mut tick = braking_from + 5;
        let mut before = speed;
        while before > 0.0 {
            hear(&mut task, command(tick - 1, 0.0, 0.2));
            let truth = truth_through(&mut task, tick);
            let expected = (before - decel * dt_s).max(0.0);
            assert!(
                (truth.applied[0] - expected).abs() < 1e-12,
                "tick {tick}: {truth:?}"
            );
            assert_eq!(truth.applied[1], 0.2, "tick {tick} turns as told");
            let ramping = u32::from(expected > 0.0) * 2;
            assert_eq!(truth.watchdog, ramping, "tick {tick}");
            (before, tick) = (truth.applied[0], tick + 1);
        }
        // Once at the commands' speed, the base takes them as they come.
        hear(&mut task, command(tick - 1, 0.3, -0.1));
        let truth = truth_through(&mut task, tick);
        assert_eq!((truth.applied, truth.watchdog), ([0.3, -0.1], 0));
        // Commands faster than the base are ramped up to as well.
        assert_eq!(
            resumed_command([0.25, 0.0], [0.9, 0.5], 0.5, 0.5),
            [0.5, 0.5]
        );
    }
}
