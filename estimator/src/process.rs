//! `scmpc estimator`: on each measurement, predict with the actuation heard for the
//! previous tick, update, and publish the estimate. In lockstep a measurement waits until
//! that actuation has been heard; in real time the newest actuation heard is used.

use crate::Estimator;
use protocol::ipc::{ACTUATION, ESTIMATE, MEASUREMENT};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError, RunMode, keep_newest};
use protocol::{Actuation, Estimate, Header, Measurement, Role};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Estimator)?;
    let measurements = link.input::<Measurement>(MEASUREMENT, Role::Plant)?;
    let actuation = link.input::<Actuation>(ACTUATION, Role::Dfl)?;
    let estimates = link.output::<Estimate>(ESTIMATE)?;

    let scenario = &args.scenario;
    let dt = scenario.timing.dt_s();
    let mut estimator = Estimator::new(scenario);
    let mut heard: Option<Actuation> = None;
    let mut queue: VecDeque<(Measurement, u64)> = VecDeque::with_capacity(16);
    let mut last_tick: Option<u64> = None;
    link.run(&[&measurements, &actuation], &[&estimates], |ctl| {
        // The periodic input first: its receipt time is the hop latency.
        measurements.take(|m, latency| queue.push_back((m, latency)))?;
        actuation.take(|a, _| keep_newest(&mut heard, a))?;
        while let Some(&(m, latency)) = queue.front() {
            let tick = m.header.tick;
            if last_tick.is_some_and(|last| tick <= last) {
                queue.pop_front(); // a replay of a tick already estimated
                continue;
            }
            let previous = heard.filter(|a| a.header.tick < tick);
            // Lockstep: the actuation of tick - 1 is still on its way. Not so for the first
            // measurement of an estimator that joined a running loop (its filter starts
            // at the measurement), nor once a newer actuation was heard.
            if args.mode == RunMode::Lockstep
                && last_tick.is_some()
                && previous.is_none_or(|a| a.header.tick + 1 != tick)
                && heard.is_none_or(|a| a.header.tick < tick)
            {
                break;
            }
            queue.pop_front();
            last_tick = Some(tick);
            let applied = previous.filter(|_| tick > 0).map(|a| [a.u1, a.u2]);
            let zeta = previous.map_or(scenario.robot.zeta0, |a| a.zeta);
            let header = Header {
                tick,
                time_s: m.header.time_s,
                input_latency_ns: latency.min(u64::from(u32::MAX)) as u32,
                ..Header::default()
            };
            let mut estimate = estimator.step(applied, dt, m.y, zeta, header);
            if args.epoch == 0 && m.header.time_s >= scenario.fault.estimator_nan_from_s {
                estimate.state[0] = f64::NAN;
            }
            if scenario.fault.estimator_delay_ms > 0.0 {
                std::thread::sleep(std::time::Duration::from_secs_f64(
                    scenario.fault.estimator_delay_ms * 1e-3,
                ));
            }
            estimates.send(estimate)?;
        }
        // Real time: the next measurement is due at the next tick; poll for it there.
        let due = last_tick.and_then(|last| ctl.at_ns(scenario.timing.tick_time_s(last + 1)));
        Ok(match (args.mode, due) {
            (RunMode::Realtime, Some(at_ns)) => Next::Expect {
                input: &measurements,
                at_ns,
            },
            _ => Next::Wait(None),
        })
    })
}
