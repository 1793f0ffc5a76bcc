//! The plant role as a task ([`protocol::task`]): tick `j` is due at `t_j`; it integrates
//! the actuation of tick `j - 1` over `[t_(j-1), t_j)` and outputs the truth and the
//! measurement of tick `j`.

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
    /// stands still).
    fn step(&mut self, context: &impl Context) -> Option<Publish<PlantOutput>> {
        let tick = self.tick;
        let due_s = self.timing.tick_time_s(tick);
        let previous_heard = self.held.is_some_and(|a| a.header.tick + 1 >= tick);
        if !context.has_reached(due_s) || !(tick == 0 || previous_heard || context.is_past(due_s)) {
            return None;
        }
        if tick > 0 {
            let [u1, u2] = self.held.map_or([0.0; 2], |a| [a.u1, a.u2]);
            self.plant.step(u1, u2, self.timing.dt_s());
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
        };
        let measurement = Measurement {
            header,
            y: self.plant.measure(),
        };
        Some(Publish::now(PlantOutput { truth, measurement }))
    }
}
