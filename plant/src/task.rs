//! The plant role as a task ([`protocol::task`]): tick `j` is due at `t_j`; it integrates
//! the actuation of tick `j - 1` over `[t_(j-1), t_j)` and outputs the truth and the
//! measurement of tick `j`.
//!
//! Like a real base's command watchdog, the plant brakes on its own once its newest
//! command is `plant.command_timeout_s` old: a DFL on a host that is lost can no longer
//! brake it ([`watchdog_command`]).

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
        let mut watchdog = false;
        if tick > 0 {
            let dt_s = self.timing.dt_s();
            let [u1, u2] = match self.held {
                None => [0.0; 2],
                // The held command was for tick `k`, over `[t_k, t_(k+1))`.
                Some(a) if (tick - 1).saturating_sub(a.header.tick) > self.timeout_ticks => {
                    watchdog = true;
                    watchdog_command(self.plant.speeds(), self.brake_decel, dt_s)
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
            watchdog: u32::from(watchdog),
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
}
