//! Lockstep held to real time (`live.pace`, docs/foxglove.md): for a live view of a
//! lockstep run that moves as the robot would.

use crate::sinks::Recording;
use protocol::Scenario;
use std::time::{Duration, Instant};

/// Holds tick `k` until `k` inner periods after the first tick.
pub struct Pace {
    first: Option<Instant>,
    period_s: f64,
}

impl Pace {
    /// The pace of `scenario`'s lockstep run, if it is served live (`recording`: never a
    /// study's) and its live view asks for one.
    pub fn of(scenario: &Scenario, recording: Recording) -> Option<Pace> {
        let live = scenario.live.as_ref().filter(|_| recording.live);
        live.filter(|l| l.pace).map(|_| Pace {
            first: None,
            period_s: scenario.timing.dt_s(),
        })
    }

    /// Returns at tick `tick`'s time.
    pub fn wait(&mut self, tick: u64) {
        let first = *self.first.get_or_insert_with(Instant::now);
        let due = first + Duration::from_secs_f64(self.period_s * tick as f64);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
    }
}
