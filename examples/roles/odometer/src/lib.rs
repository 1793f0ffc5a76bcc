//! An example role, to copy when adding one (docs/design.md, "Adding a role"): the
//! odometer takes every estimate of the robot's pose and publishes, at every MPC sample,
//! the distance the estimate has driven since the process started ([`protocol::Odometry`]:
//! a restarted or swapped-in odometer starts again from 0).
//! It runs when a scenario names it (`extra_roles = ["odometer"]`), in process and as a
//! process of its own (`scmpc odometer`), and the record writes its samples to
//! `odometry.csv` and `run.mcap`'s `/odometer/odometry` with no code of its own.

use protocol::task::{Context, Due, Publish, Task, TaskError};
use protocol::{Estimate, Header, Odometry, Role, Validated};
use std::collections::VecDeque;

/// What the odometer takes: the estimator's estimates.
#[derive(Debug, Clone, Copy)]
pub enum OdometerInput {
    Estimate(Estimate),
}
protocol::task_input!(OdometerInput: Estimate);

/// The distance driven along a path of positions, m: what [`OdometerTask`] integrates.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Odometer {
    /// The newest position, `[x_m, y_m]`.
    last: Option<[f64; 2]>,
    pub distance_m: f64,
}

impl Odometer {
    /// Adds the straight segment from the previous position to `position`; a position
    /// that is not finite is left out (the border check refuses such an estimate before
    /// a task hears it; the odometer does not count on it).
    pub fn add(&mut self, position: [f64; 2]) {
        if !position.iter().all(|p| p.is_finite()) {
            return;
        }
        if let Some([x, y]) = self.last {
            self.distance_m += (position[0] - x).hypot(position[1] - y);
        }
        self.last = Some(position);
    }
}

/// The odometer role's task.
pub struct OdometerTask {
    odometer: Odometer,
    ticks_per_sample: u64,
    dt_s: f64,
    /// The newest tick heard.
    last_tick: Option<u64>,
    /// The readings at the first ticks of samples heard and not published yet, oldest
    /// first (the estimates of several ticks may come before a step).
    due: VecDeque<Odometry>,
}

impl Task for OdometerTask {
    const ROLE: Role = Role::Odometer;
    type Input = OdometerInput;
    type Output = Odometry;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<Self, TaskError> {
        Ok(OdometerTask {
            odometer: Odometer::default(),
            ticks_per_sample: scenario.timing.ticks_per_sample(),
            dt_s: scenario.timing.dt_s(),
            last_tick: None,
            due: VecDeque::with_capacity(4),
        })
    }

    /// An estimate newer than the last is integrated (a replay is not); at a sample's
    /// first tick the distance so far is due to be published.
    fn hear(&mut self, input: OdometerInput, _latency_ns: u64, _context: &impl Context) {
        let OdometerInput::Estimate(estimate) = input;
        let tick = estimate.header.tick;
        if self.last_tick.is_some_and(|last| tick <= last) {
            return;
        }
        self.last_tick = Some(tick);
        let [x, y, ..] = estimate.state;
        self.odometer.add([x, y]);
        if tick.is_multiple_of(self.ticks_per_sample) {
            self.due.push_back(Odometry {
                header: Header {
                    tick,
                    time_s: estimate.header.time_s,
                    ..Header::default()
                },
                distance_m: self.odometer.distance_m,
            });
        }
    }

    /// The oldest reading due.
    fn step(&mut self, _context: &impl Context) -> Option<Publish<Odometry>> {
        Some(Publish {
            output: self.due.pop_front()?,
            hold_ns: 0,
        })
    }

    /// The next tick's estimate is expected.
    fn next(&self) -> Due {
        let next = self.last_tick.map_or(0, |last| last + 1);
        Due::Expect(Some(next as f64 * self.dt_s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_distance_is_the_length_of_the_path_and_a_silent_estimate_adds_nothing() {
        let mut odometer = Odometer::default();
        for position in [[0.0, 0.0], [3.0, 4.0], [f64::NAN, 0.0], [3.0, 5.0]] {
            odometer.add(position);
        }
        assert_eq!(odometer.distance_m, 6.0);
    }
}
