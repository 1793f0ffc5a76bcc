//! The lidar role (docs/running.md, "A lidar"): at every perception tick of the plant's
//! truth it scans the world, every obstacle at its true place at that tick's time (the
//! ones the pipeline knows and the ones it does not), and in a fleet every other robot
//! (docs/fleet.md, "A lidar in a fleet"), and publishes the scan. Math in [`sensor`]; no
//! I/O, no clock.

pub mod sensor;
pub use sensor::{Disc, Lidar};

use protocol::task::{Context, Due, PerceptionTicks, Publish, Recent, Task, TaskError};
use protocol::{Data, GroundTruth, Header, Obstacle, Role, Scan, Validated};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;

/// What the lidar takes: the plant's truth (the robot's pose, and the clock of the world).
#[derive(Debug, Clone, Copy)]
pub enum LidarInput {
    Truth(GroundTruth),
}
protocol::task_input!(LidarInput: Truth);

/// The sensor, the world it scans, and the perception ticks waiting.
pub struct LidarTask {
    lidar: Lidar,
    obstacles: Vec<Obstacle>,
    /// The obstacles' discs at the scan's time (kept to scan without allocating).
    discs: Vec<Disc>,
    /// Its own stream: the plant's noise stays what it was without a lidar.
    rng: ChaCha8Rng,
    perception: PerceptionTicks,
    /// Truths of perception ticks heard and not scanned yet.
    pending: VecDeque<GroundTruth>,
    /// The other robots of a fleet.
    peers: Vec<Peer>,
    /// The inner tick, s: the unit of a peer's truths' ticks.
    dt_s: f64,
}

/// Another robot of a fleet as the lidar sees it: a disc of its footprint, where its own
/// truths put it.
struct Peer {
    id: u32,
    radius_m: f64,
    /// Where it is before a truth of it is heard.
    start: [f64; 2],
    /// Its true positions, m.
    truths: Recent<[f64; 2]>,
}

/// The lidar's seed beside the scenario's (`"lidar"` in ASCII).
const SEED_STREAM: u64 = 0x6c_6964_6172;

impl Task for LidarTask {
    const ROLE: Role = Role::Lidar;
    type Input = LidarInput;
    type Output = Scan;
    type Resources = ();

    fn new(scenario: &Validated, _epoch: u32, _resources: ()) -> Result<LidarTask, TaskError> {
        let config = scenario.lidar.clone().unwrap_or_default();
        Ok(LidarTask {
            lidar: Lidar::of(&config),
            obstacles: scenario.obstacles.clone(),
            discs: Vec::with_capacity(scenario.obstacles.len() + scenario.robots.len()),
            rng: ChaCha8Rng::seed_from_u64(scenario.seed ^ SEED_STREAM),
            perception: PerceptionTicks::of(scenario),
            pending: VecDeque::with_capacity(8),
            peers: peers_of(scenario),
            dt_s: scenario.timing.dt_s(),
        })
    }

    /// In a fleet, another robot's truth: the lidar sees it.
    fn hear_peer(&mut self, data: &Data) {
        let Data::Truth(truth) = data else {
            return;
        };
        if let Some(peer) = (self.peers.iter_mut()).find(|p| p.id == truth.header.robot) {
            let [x, y, _] = truth.pose;
            peer.truths.push(truth.header.tick, [x, y]);
        }
    }

    /// A truth at a perception tick newer than the last is queued.
    fn hear(&mut self, input: LidarInput, _latency_ns: u64, _context: &impl Context) {
        let LidarInput::Truth(truth) = input;
        if self.perception.take(truth.header.tick) {
            self.pending.push_back(truth);
        }
    }

    /// The next perception tick's truth is expected.
    fn next(&self) -> Due {
        Due::Expect(Some(self.perception.next_s()))
    }

    /// The scan of the oldest perception tick waiting.
    fn step(&mut self, _context: &impl Context) -> Option<Publish<Scan>> {
        let truth = self.pending.pop_front()?;
        Some(Publish::now(self.scan(&truth)))
    }
}

impl LidarTask {
    /// The scan from where `truth` has the robot, at its time: of the obstacles, and of
    /// the other robots where their truths before this tick put them, moved on by a tick
    /// ([`Recent::position_at`]; so in process and in lockstep a scan does not depend on
    /// whether another robot has stepped this tick). The positions of one tick are off by
    /// the change of that velocity in a tick, under 0.1 mm at a robot's input box.
    fn scan(&mut self, truth: &GroundTruth) -> Scan {
        let (tick, time_s) = (truth.header.tick, truth.header.time_s);
        self.discs.clear();
        (self.discs).extend(
            self.obstacles
                .iter()
                .map(|o| (o.center_at(time_s), o.radius)),
        );
        let dt_s = self.dt_s;
        (self.discs).extend(self.peers.iter().map(|p| {
            let position = p.truths.position_at(tick, time_s, dt_s);
            (position.unwrap_or(p.start), p.radius_m)
        }));
        let header = Header {
            tick: truth.header.tick,
            time_s,
            ..Header::default()
        };
        (self.lidar).scan_message(header, truth.pose, &self.discs, &mut self.rng)
    }
}

/// The other robots of `scenario`'s fleet, seen by its member; none for a robot alone.
fn peers_of(scenario: &Validated) -> Vec<Peer> {
    (scenario.other_robots())
        .map(|(id, [x, y, _], radius_m)| Peer {
            id: id as u32,
            radius_m,
            start: [x, y],
            truths: Recent::of_two_samples(scenario.timing.inner_steps),
        })
        .collect()
}

#[cfg(test)]
mod tests;
