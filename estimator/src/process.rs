//! `scmpc estimator`: on each measurement, predict with the actuation heard for the
//! previous tick, update, and publish the estimate. In lockstep a measurement waits until
//! that actuation has been heard; in real time the newest actuation heard is used.

use crate::Estimator;
use protocol::ipc::{
    self, ACTUATION, ControlState, ESTIMATE, Link, MEASUREMENT, ProcessArgs, ProcessError, RunMode,
    open_topic,
};
use protocol::{Actuation, Estimate, Header, Measurement, Role, StatusEvent};
use std::collections::VecDeque;

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Estimator)?;
    let mut ctl = ControlState::default();
    let measurements =
        open_topic::<Measurement>(&link.node, MEASUREMENT)?.receiver_from(Role::Plant)?;
    let actuation = open_topic::<Actuation>(&link.node, ACTUATION)?.receiver_from(Role::Dfl)?;
    let estimates = open_topic::<Estimate>(&link.node, ESTIMATE)?.sender(args.epoch)?;
    let waitset = ipc::waitset(true)?;
    let _guards = [
        link.control().attach(&waitset)?,
        measurements.attach(&waitset)?,
        actuation.attach(&waitset)?,
    ];
    link.report(StatusEvent::Ready)?;

    let timing = &args.scenario.timing;
    let dt = timing.dt_s();
    let mut estimator = Estimator::new(&args.scenario);
    let mut heard: Option<Actuation> = None;
    let mut queue: VecDeque<(Measurement, u64)> = VecDeque::with_capacity(16);
    let mut last_tick: Option<u64> = None;
    let mut cleared = false;
    loop {
        // Hot path: samples straight from shared memory, the periodic input first (its
        // receipt time is the hop latency); system calls come after publishing.
        measurements.take(|m, latency| queue.push_back((m, latency)))?;
        actuation.take(|a, _| {
            if heard.is_none_or(|h| a.header.tick >= h.header.tick) {
                heard = Some(a);
            }
        })?;
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
            let zeta = previous.map_or(args.scenario.robot.zeta0, |a| a.zeta);
            let header = Header {
                tick,
                time_s: m.header.time_s,
                input_latency_ns: latency.min(u64::from(u32::MAX)) as u32,
                ..Header::default()
            };
            let estimate = estimator.step(applied, dt, m.y, zeta, header);
            if args.scenario.fault.estimator_delay_ms > 0.0 {
                std::thread::sleep(std::time::Duration::from_secs_f64(
                    args.scenario.fault.estimator_delay_ms * 1e-3,
                ));
            }
            estimates.send(estimate)?;
        }
        if !cleared {
            // Consume the wake-ups, then take once more what came before that.
            if !link.housekeeping(&mut ctl, &[&measurements, &actuation])? {
                return Ok(());
            }
            if ctl.take_replay() {
                estimates.replay()?;
            }
            cleared = true;
            continue;
        }
        cleared = false;
        // Real time: the next measurement is due at the next tick; poll for it there.
        if let (RunMode::Realtime, Some(start_ns), Some(last)) =
            (args.mode, ctl.start_ns, last_tick)
        {
            let expected = start_ns + (timing.tick_time_s(last + 1) * 1e9) as u64;
            if ipc::spin_wait(expected, || measurements.has_samples()) {
                continue;
            }
        }
        if !link.wait(&waitset, None)? {
            return Ok(());
        }
    }
}
