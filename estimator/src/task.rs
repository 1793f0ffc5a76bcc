//! The estimator role as a task ([`protocol::task`]): each measurement, in tick order, is
//! predicted to with the actuation of the tick before it and then taken in; the estimate
//! carries the DFL's zeta from that actuation. A filter that starts mid-run (a restart, a
//! swap, a failover) starts at its first measurement, with zeta from the base's odometry:
//! it waits for no actuation, which a DFL lost at the same time would never send.

use crate::Estimator;
use protocol::task::{Context, Due, Publish, Task, TaskError, header_latency, keep_newest};
use protocol::{Actuation, Estimate, FaultConfig, Header, Measurement, Role, Validated};
use std::collections::VecDeque;

/// What the estimator takes: the plant's measurements (periodic) and the DFL's commands.
#[derive(Debug, Clone, Copy)]
pub enum EstimatorInput {
    Measurement(Measurement),
    Actuation(Actuation),
}
protocol::task_input!(EstimatorInput: Measurement, Actuation);

/// The estimator with the measurements waiting for it.
pub struct EstimatorTask {
    estimator: Estimator,
    dt_s: f64,
    zeta0: f64,
    /// The producer epoch of this process: the injected NaN fault is the first one's.
    epoch: u32,
    faults: FaultConfig,
    /// The newest actuation heard.
    heard: Option<Actuation>,
    /// Measurements not estimated yet, with their publish-to-receipt latency, ns.
    queue: VecDeque<(Measurement, u64)>,
    /// The newest tick estimated.
    last_tick: Option<u64>,
}

impl Task for EstimatorTask {
    const ROLE: Role = Role::Estimator;
    type Input = EstimatorInput;
    type Output = Estimate;
    type Resources = ();

    /// The task of the process with producer epoch `epoch` (the injected NaN fault is the
    /// first one's).
    fn new(scenario: &Validated, epoch: u32, _resources: ()) -> Result<EstimatorTask, TaskError> {
        Ok(EstimatorTask {
            estimator: Estimator::new(scenario),
            dt_s: scenario.timing.dt_s(),
            zeta0: scenario.robot.zeta0,
            epoch,
            faults: scenario.fault.clone(),
            heard: None,
            queue: VecDeque::with_capacity(16),
            last_tick: None,
        })
    }

    /// A measurement is queued with its receipt latency; of the actuations the newest is
    /// kept.
    fn hear(&mut self, input: EstimatorInput, latency_ns: u64, _context: &impl Context) {
        match input {
            EstimatorInput::Measurement(m) => self.queue.push_back((m, latency_ns)),
            EstimatorInput::Actuation(a) => keep_newest(&mut self.heard, a),
        }
    }

    /// The next measurement is expected at its tick's time (not known before the first).
    fn next(&self) -> Due {
        Due::Expect(self.last_tick.map(|last| (last + 1) as f64 * self.dt_s))
    }

    /// The estimate of the oldest measurement waiting, once the actuation of the tick
    /// before it is heard, a newer one is, or its time is past (then with the newest
    /// older one, or none: then zeta is the odometry's speed). The first measurement a
    /// task takes starts its filter at once (at tick 0 with `robot.zeta0`, later with the
    /// odometry's speed). A slow estimator (`fault.estimator_delay_ms`) holds every
    /// estimate that long.
    fn step(&mut self, context: &impl Context) -> Option<Publish<Estimate>> {
        while let Some(&(m, latency_ns)) = self.queue.front() {
            let tick = m.header.tick;
            if self.last_tick.is_some_and(|last| tick <= last) {
                self.queue.pop_front(); // a replay of a tick already estimated
                continue;
            }
            let previous = self.heard.filter(|a| a.header.tick < tick);
            let waiting = self.last_tick.is_some()
                && previous.is_none_or(|a| a.header.tick + 1 != tick)
                && self.heard.is_none_or(|a| a.header.tick < tick)
                && !context.is_past(m.header.time_s);
            if waiting {
                return None;
            }
            self.queue.pop_front();
            let output = self.estimate(&m, latency_ns, previous);
            self.last_tick = Some(tick);
            return Some(Publish {
                output,
                hold_ns: (self.faults.estimator_delay_ms * 1e6) as u64,
            });
        }
        None
    }
}

impl EstimatorTask {
    fn estimate(
        &mut self,
        m: &Measurement,
        latency_ns: u64,
        previous: Option<Actuation>,
    ) -> Estimate {
        let applied = previous.filter(|_| m.header.tick > 0).map(|a| [a.u1, a.u2]);
        // The DFL's zeta, from the actuation of the tick before; a filter started mid-run,
        // or one without that actuation (late, or none came: the base's watchdog may have
        // braked it), takes the base's speed from its odometry.
        let tick = m.header.tick;
        let zeta = if tick == 0 {
            self.zeta0
        } else if let Some(a) =
            previous.filter(|a| self.last_tick.is_some() && a.header.tick + 1 == tick)
        {
            a.zeta
        } else {
            m.odometry[0]
        };
        if self.last_tick.is_none() && tick > 0 {
            self.estimator.start_base_at(m.odometry);
        }
        let header = Header {
            tick: m.header.tick,
            time_s: m.header.time_s,
            input_latency_ns: header_latency(latency_ns),
            ..Header::default()
        };
        let mut estimate = self.estimator.step(applied, self.dt_s, m.y, zeta, header);
        if self.epoch == 0 && m.header.time_s >= self.faults.estimator_nan_from_s {
            estimate.state[0] = f64::NAN;
            estimate.ahead[0] = f64::NAN;
        }
        estimate
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::Scenario;
    use protocol::task::SimulatedTime;

    fn measurement(tick: u64, dt_s: f64, odometry: [f64; 2]) -> Measurement {
        Measurement {
            header: Header {
                tick,
                time_s: tick as f64 * dt_s,
                ..Header::default()
            },
            y: [1.0, 2.0, 0.3],
            odometry,
        }
    }

    #[test]
    fn an_estimator_that_starts_mid_run_waits_for_no_actuation_and_takes_zeta_from_odometry() {
        let scenario = Scenario::paper().validated("test").expect("valid");
        let dt_s = scenario.timing.dt_s();
        let mut task = EstimatorTask::new(&scenario, 3, ()).expect("estimator");
        // In lockstep: the clock stands at the measurement's tick, which is never past.
        let at = |tick| SimulatedTime::at(tick, dt_s);
        let first = measurement(50, dt_s, [0.7, 0.1]);
        task.hear(EstimatorInput::Measurement(first), 0, &at(50));
        let estimate = task
            .step(&at(50))
            .expect("a new filter starts at once")
            .output;
        assert_eq!(estimate.header.tick, 50);
        assert_eq!(estimate.state[3], 0.7, "zeta from the odometry");
        let next = measurement(51, dt_s, [0.75, 0.1]);
        task.hear(EstimatorInput::Measurement(next), 0, &at(51));
        assert!(
            task.step(&at(51)).is_none(),
            "then waits for tick 50's actuation"
        );
        let actuation = Actuation {
            header: Header {
                tick: 50,
                ..Header::default()
            },
            u1: 0.72,
            zeta: 0.74,
            ..Actuation::default()
        };
        task.hear(EstimatorInput::Actuation(actuation), 0, &at(51));
        let estimate = task.step(&at(51)).expect("estimated").output;
        assert_eq!(estimate.state[3], 0.74, "zeta from the DFL's actuation");
    }
}
