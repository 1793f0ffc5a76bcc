//! `scmpc plant`: the plant as a process. Lockstep: on each clock grant, integrate over the
//! last tick with the actuation of that tick, then publish truth and measurement. Real
//! time: the same at absolute monotonic deadlines, holding the newest actuation received.

use crate::Plant;
use protocol::clock::sleep_until_ns;
use protocol::ipc::{
    self, ACTUATION, ControlState, Link, MEASUREMENT, ProcessArgs, ProcessError, RunMode, TRUTH,
    open_topic,
};
use protocol::{Actuation, GroundTruth, Header, Measurement, Role, StatusEvent};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Plant)?;
    let mut ctl = ControlState::default();
    let measurement = open_topic::<Measurement>(&link.node, MEASUREMENT)?.sender(args.epoch)?;
    let truth = open_topic::<GroundTruth>(&link.node, TRUTH)?.sender(args.epoch)?;
    let actuation = open_topic::<Actuation>(&link.node, ACTUATION)?.receiver_from(Role::Dfl)?;
    let waitset = ipc::waitset(true)?;
    let _control = link.control().attach(&waitset)?;
    let _actuation = actuation.attach(&waitset)?;
    link.report(StatusEvent::Ready)?;

    let timing = &args.scenario.timing;
    let dt = timing.dt_s();
    let mut plant = Plant::new(&args.scenario);
    let mut latest: Option<Actuation> = None;
    let publish =
        |plant: &mut Plant, tick: u64, input_latency_ns: u64| -> Result<(), ProcessError> {
            let header = Header {
                tick,
                time_s: timing.tick_time_s(tick),
                input_latency_ns: input_latency_ns.min(u64::from(u32::MAX)) as u32,
                ..Header::default()
            };
            truth.send(GroundTruth {
                header,
                pose: plant.pose(),
            })?;
            measurement.send(Measurement {
                header,
                y: plant.measure(),
            })?;
            Ok(())
        };
    let mut tick = 0u64;
    loop {
        if !link.housekeeping(&mut ctl, &[&actuation])? {
            return Ok(());
        }
        if ctl.take_replay() {
            truth.replay()?;
            measurement.replay()?;
        }
        actuation.take(|a, _| {
            if latest.is_none_or(|l| a.header.tick >= l.header.tick) {
                latest = Some(a);
            }
        })?;
        match args.mode {
            RunMode::Lockstep => {
                // Tick j needs the grant for j and the actuation of tick j - 1.
                let granted = ctl.granted.filter(|(g, _)| *g == tick);
                let have_input = tick == 0 || latest.is_some_and(|a| a.header.tick + 1 == tick);
                if let (Some((_, grant_latency)), true) = (granted, have_input) {
                    if let Some(a) = latest.filter(|_| tick > 0) {
                        plant.step(a.u1, a.u2, dt);
                    }
                    publish(&mut plant, tick, grant_latency)?;
                    tick += 1;
                    continue;
                }
            }
            RunMode::Realtime => {
                if let Some(start_ns) = ctl.start_ns {
                    let deadline = start_ns + (timing.tick_time_s(tick) * 1e9) as u64;
                    sleep_until_ns(deadline);
                    actuation.drain(|a, _| {
                        if latest.is_none_or(|l| a.header.tick >= l.header.tick) {
                            latest = Some(a);
                        }
                    })?;
                    if tick > 0 {
                        // Hold the newest actuation; with none yet, stand still.
                        let [u1, u2] = latest.map_or([0.0; 2], |a| [a.u1, a.u2]);
                        plant.step(u1, u2, dt);
                    }
                    publish(&mut plant, tick, 0)?;
                    tick += 1;
                    if link.node.wait(std::time::Duration::ZERO).is_err() {
                        return Ok(());
                    }
                    continue;
                }
            }
        }
        if !link.wait(&waitset, None)? {
            return Ok(());
        }
    }
}
