//! `scmpc plant`: the plant as a process. Lockstep: on each clock grant, integrate over the
//! last tick with the actuation of that tick, then publish truth and measurement. Real
//! time: the same at absolute monotonic deadlines, holding the newest actuation received.

use crate::Plant;
use protocol::clock::sleep_until_ns;
use protocol::ipc::{ACTUATION, MEASUREMENT, TRUTH};
use protocol::runtime::{Link, Next, ProcessArgs, ProcessError, RunMode, keep_newest};
use protocol::{Actuation, GroundTruth, Header, Measurement, Role};

pub fn run(args: &ProcessArgs) -> Result<(), ProcessError> {
    let link = Link::open(args, Role::Plant)?;
    let measurement = link.output::<Measurement>(MEASUREMENT)?;
    let truth = link.output::<GroundTruth>(TRUTH)?;
    let actuation = link.input::<Actuation>(ACTUATION, Role::Dfl)?;

    let timing = &args.scenario.timing;
    let dt = timing.dt_s();
    let mut plant = Plant::new(&args.scenario);
    let mut latest: Option<Actuation> = None;
    let mut tick = 0u64;
    let publish = |plant: &mut Plant, tick: u64, input_latency_ns: u64| {
        let header = Header {
            tick,
            time_s: timing.tick_time_s(tick),
            input_latency_ns: input_latency_ns.min(u64::from(u32::MAX)) as u32,
            ..Header::default()
        };
        let pose = plant.pose();
        truth.send(GroundTruth { header, pose })?;
        measurement.send(Measurement {
            header,
            y: plant.measure(),
        })
    };
    link.run(&[&actuation], &[&truth, &measurement], |ctl| {
        match (args.mode, ctl.at_ns(timing.tick_time_s(tick))) {
            (RunMode::Lockstep, _) => {
                actuation.take(|a, _| keep_newest(&mut latest, a))?;
                // Tick j needs the grant for j and the actuation of tick j - 1.
                let granted = ctl.granted.filter(|(g, _)| *g == tick);
                let have_input = tick == 0 || latest.is_some_and(|a| a.header.tick + 1 == tick);
                if let (Some((_, grant_latency)), true) = (granted, have_input) {
                    if let Some(a) = latest.filter(|_| tick > 0) {
                        plant.step(a.u1, a.u2, dt);
                    }
                    publish(&mut plant, tick, grant_latency)?;
                    tick += 1;
                }
                Ok(Next::Wait(None))
            }
            (RunMode::Realtime, Some(deadline_ns)) => {
                sleep_until_ns(deadline_ns);
                actuation.drain(|a, _| keep_newest(&mut latest, a))?;
                if tick > 0 {
                    // Hold the newest actuation; with none yet, stand still.
                    let [u1, u2] = latest.map_or([0.0; 2], |a| [a.u1, a.u2]);
                    plant.step(u1, u2, dt);
                }
                publish(&mut plant, tick, 0)?;
                tick += 1;
                Ok(Next::Again)
            }
            (RunMode::Realtime, None) => {
                actuation.take(|a, _| keep_newest(&mut latest, a))?;
                Ok(Next::Wait(None))
            }
        }
    })
}
