//! The estimator role as a task ([`protocol::task`]): each measurement, in tick order, is
//! predicted to with the actuation of the tick before it and then taken in; the estimate
//! carries the DFL's zeta from that actuation.

use crate::Estimator;
use protocol::task::{Context, header_latency, keep_newest};
use protocol::{Actuation, Estimate, FaultConfig, Header, Measurement, Scenario};
use std::collections::VecDeque;

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

impl EstimatorTask {
    /// The task of the process with producer epoch `epoch`.
    pub fn new(scenario: &Scenario, epoch: u32) -> EstimatorTask {
        EstimatorTask {
            estimator: Estimator::new(scenario),
            dt_s: scenario.timing.dt_s(),
            zeta0: scenario.robot.zeta0,
            epoch,
            faults: scenario.fault.clone(),
            heard: None,
            queue: VecDeque::with_capacity(16),
            last_tick: None,
        }
    }

    /// A measurement received `latency_ns` after it was published.
    pub fn hear_measurement(&mut self, measurement: Measurement, latency_ns: u64) {
        self.queue.push_back((measurement, latency_ns));
    }

    /// An actuation heard (the newest is kept).
    pub fn hear_actuation(&mut self, actuation: Actuation) {
        keep_newest(&mut self.heard, actuation);
    }

    /// When the next measurement is due, s (`None` before the first).
    pub fn next_due_s(&self) -> Option<f64> {
        self.last_tick.map(|last| (last + 1) as f64 * self.dt_s)
    }

    /// How long a process of the estimator takes to publish each estimate
    /// (`fault.estimator_delay_ms`): a slow estimator in real time, a slower run in
    /// lockstep, nothing in process.
    pub fn publish_delay(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.faults.estimator_delay_ms * 1e-3)
    }

    /// The estimate of the oldest measurement waiting, once the actuation of the tick
    /// before it is heard, a newer one is, or its time is past (then with the newest
    /// older one). The first measurement a task takes starts its filter; a task that joins
    /// a running loop hears the actuation it needs again (the executor has every producer
    /// repeat its newest sample for it).
    pub fn step(&mut self, context: &impl Context) -> Option<Estimate> {
        while let Some(&(m, latency_ns)) = self.queue.front() {
            let tick = m.header.tick;
            if self.last_tick.is_some_and(|last| tick <= last) {
                self.queue.pop_front(); // a replay of a tick already estimated
                continue;
            }
            let previous = self.heard.filter(|a| a.header.tick < tick);
            let waiting = tick > 0
                && previous.is_none_or(|a| a.header.tick + 1 != tick)
                && self.heard.is_none_or(|a| a.header.tick < tick)
                && !context.clock().is_past(m.header.time_s);
            if waiting {
                return None;
            }
            self.queue.pop_front();
            self.last_tick = Some(tick);
            return Some(self.estimate(&m, latency_ns, previous));
        }
        None
    }

    fn estimate(
        &mut self,
        m: &Measurement,
        latency_ns: u64,
        previous: Option<Actuation>,
    ) -> Estimate {
        let applied = previous.filter(|_| m.header.tick > 0).map(|a| [a.u1, a.u2]);
        let zeta = previous.map_or(self.zeta0, |a| a.zeta);
        let header = Header {
            tick: m.header.tick,
            time_s: m.header.time_s,
            input_latency_ns: header_latency(latency_ns),
            ..Header::default()
        };
        let mut estimate = self.estimator.step(applied, self.dt_s, m.y, zeta, header);
        if self.epoch == 0 && m.header.time_s >= self.faults.estimator_nan_from_s {
            estimate.state[0] = f64::NAN;
        }
        estimate
    }
}
