//! `run.mcap`: the run for Foxglove (docs/foxglove.md).
//!
//! Messages are JSON with a JSON Schema. Channels whose schema is named after one of
//! Foxglove's well-known schemas (`foxglove.PoseInFrame`, `foxglove.PosesInFrame`,
//! `foxglove.SceneUpdate`, `foxglove.Log`) show in its 3D and log panels without
//! configuration; the `scmpc.*` channels carry the numbers for its plot panel. Every
//! message is logged at its simulated time, so the timeline is the run's clock.
//!
//! The writer lives in the orchestrator, on a thread of its own: the recorder hands it
//! copies of the messages ([`Encoded`]), and the thread encodes and writes them, so the
//! recording costs the orchestrator's loop a copy per message. The messages of every tick
//! and plan are encoded by hand ([`super::json`]), the rest by serde_json, to the same
//! bytes. The encoder is in [`encoder`], the file in [`file`], Foxglove's types and the
//! schemas in [`foxglove`]. A live view (the `live` crate) is the same encoder on channels
//! of its own ([`Channels`]).

mod encoder;
mod file;
mod foxglove;
mod merge;

use super::json::{Json, json_object};
use encoder::Encoder;
pub use file::McapFile;
use foxglove::*;
pub use merge::{fleet_topic, merge_fleet};
use protocol::{
    Actuation, CommandMode, DeadlineVerdict, Estimate, GroundTruth, PLAN_MISSING, Plan, PlanStatus,
    Route, Scenario, Timing, Tracks,
};
use serde::Serialize;
use serde_json::{Value, json};
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

/// A channel of `run.mcap`: topic, schema name, JSON Schema.
type Channel = (&'static str, &'static str, fn() -> Value);

/// Every channel of `run.mcap`.
const CHANNELS: [Channel; 16] = [
    (
        "/world/obstacles",
        "foxglove.SceneUpdate",
        scene_update_schema,
    ),
    (
        "/world/moving_obstacles",
        "foxglove.SceneUpdate",
        scene_update_schema,
    ),
    (
        "/tracker/tracks",
        "foxglove.SceneUpdate",
        scene_update_schema,
    ),
    ("/robot/truth", "foxglove.PoseInFrame", pose_in_frame_schema),
    ("/lidar/laser_scan", "foxglove.LaserScan", laser_scan_schema),
    (
        "/robot/estimate",
        "foxglove.PoseInFrame",
        pose_in_frame_schema,
    ),
    (
        "/robot/covariance",
        "foxglove.SceneUpdate",
        scene_update_schema,
    ),
    ("/mpc/plan", "foxglove.PosesInFrame", poses_in_frame_schema),
    (
        "/planner/route",
        "foxglove.PosesInFrame",
        poses_in_frame_schema,
    ),
    ("/estimator/estimate", "scmpc.Estimate", estimate_schema),
    ("/dfl/command", "scmpc.Command", command_schema),
    ("/robot/clearance", "scmpc.Clearance", clearance_schema),
    ("/pipeline/latency", "scmpc.Latency", latency_schema),
    ("/dfl/deadline", "scmpc.DeadlineVerdict", deadline_schema),
    ("/events", "foxglove.Log", log_schema),
    ("/run/events", "scmpc.Event", crate::EventLine::schema),
];

/// The topic of every channel `run.mcap` and the live view may have (a run's are those its
/// world carries), but for the topics the record has no place of its own for.
pub fn topics() -> impl Iterator<Item = &'static str> {
    CHANNELS.iter().map(|(topic, ..)| *topic)
}

/// Whether `topic`'s channel carries messages in a run of `scenario`: a live client is
/// offered no channel that would stay silent.
fn carries(topic: &str, scenario: &Scenario) -> bool {
    let runs = |role| scenario.roles().any(|r| r == role);
    match topic {
        "/world/moving_obstacles" => scenario.obstacles.iter().any(|o| o.moves()),
        "/tracker/tracks" => runs(protocol::Role::Tracker),
        "/lidar/laser_scan" => scenario.lidar.is_some(),
        "/planner/route" => runs(protocol::Role::Planner),
        _ => true,
    }
}

/// The frame every pose is given in: the scenario's plane, z up.
const FRAME: &str = "world";
/// Height of the obstacle cylinders, m (the world is planar).
const OBSTACLE_HEIGHT_M: f64 = 0.3;
/// The covariance ellipse spans this many standard deviations each way.
const COVARIANCE_SIGMAS: f64 = 3.0;

/// A tick as the recorder hands it over.
struct TickRecord {
    truth: GroundTruth,
    estimate: Estimate,
    actuation: Actuation,
    /// The robot's clearance, m.
    clearance_m: f64,
    /// The plant's input latency (the grant's, or a ROS 2 robot's odometry age), ns; 0 in
    /// process.
    plant_input_latency_ns: u32,
}

/// What the recorder hands the writer thread.
enum Record {
    Tick(Box<TickRecord>),
    Plan(Box<Plan>),
    Route(Box<Route>),
    Tracks(Box<Tracks>),
    Verdict(DeadlineVerdict),
    /// An event, and its line of `events.jsonl`.
    Event(Box<(crate::EventLine, Value)>),
    /// A message of a topic the record has no place of its own for.
    Data(Box<protocol::Data>),
}

/// Where the encoder's messages go: `run.mcap` ([`McapFile`]), or a live view (the `live`
/// crate). Called on the encoder's thread only.
pub trait Channels: Send + 'static {
    /// Declares a channel: its topic, and its schema (a JSON Schema named `schema_name`).
    /// Every channel is added before the first message.
    fn add_channel(&mut self, topic: &str, schema_name: &str, schema: &[u8])
    -> std::io::Result<()>;
    /// A message on `topic`'s channel at simulated time `time_ns`: JSON.
    fn message(&mut self, topic: &str, time_ns: u64, json: &[u8]) -> std::io::Result<()>;
    /// Called every [`super::FLUSH_PERIOD`] at most.
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
    /// The run is over: every message has been handed over.
    fn finish(self) -> std::io::Result<()>;
}

/// How records reach the encoder's thread.
enum Handover {
    /// Every one (`run.mcap`).
    Lossless(std::sync::mpsc::Sender<Vec<Record>>),
    /// At most a bound's worth waiting; a batch that finds the queue full is dropped (a
    /// live view: what matters is the newest).
    Lossy(std::sync::mpsc::SyncSender<Vec<Record>>),
}

/// A run's messages being encoded and written to their [`Channels`] by a thread of their
/// own: `run.mcap` ([`Encoded::open_mcap`]), or a live view ([`Encoded::start_lossy`]).
pub struct Encoded {
    records: Handover,
    /// Records not handed over yet: the thread gets them in batches, so it wakes once per
    /// batch rather than once per message (in lockstep, thousands of times a second).
    batch: Vec<Record>,
    handed: Instant,
    /// What the thread is called, in its errors.
    name: &'static str,
    thread: std::thread::JoinHandle<std::io::Result<()>>,
}

/// Records per batch, and the longest a record waits for its batch.
const BATCH: usize = 64;
const BATCH_WAIT: Duration = Duration::from_millis(100);

impl Encoded {
    /// Adds every channel of `scenario`'s run to `out`, logs the world at time 0, and starts
    /// the thread, named `name`, that encodes the rest into `out`, every one.
    pub fn start<C: Channels>(
        name: &'static str,
        out: C,
        scenario: &Scenario,
    ) -> std::io::Result<Encoded> {
        let (records, received) = std::sync::mpsc::channel();
        Encoded::spawn(name, out, scenario, Handover::Lossless(records), received)
    }

    /// [`Encoded::start`], with at most `batches` batches of records waiting for the thread:
    /// one that finds them all waiting is dropped, so a thread that falls behind costs no
    /// more memory.
    pub fn start_lossy<C: Channels>(
        name: &'static str,
        out: C,
        scenario: &Scenario,
        batches: usize,
    ) -> std::io::Result<Encoded> {
        let (records, received) = std::sync::mpsc::sync_channel(batches);
        Encoded::spawn(name, out, scenario, Handover::Lossy(records), received)
    }

    fn spawn<C: Channels>(
        name: &'static str,
        out: C,
        scenario: &Scenario,
        records: Handover,
        received: std::sync::mpsc::Receiver<Vec<Record>>,
    ) -> std::io::Result<Encoded> {
        let mut encoder = Encoder::new(out, scenario)?;
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || {
                let mut flush = crate::lines::FlushClock::new();
                loop {
                    match received.recv_timeout(super::FLUSH_PERIOD) {
                        Ok(batch) => {
                            for record in batch {
                                encoder.record(record)?;
                                // In lockstep every core runs a role polling for its
                                // input (yielding between polls): give the core back after
                                // each record, so that the role whose input came runs at
                                // once, not after the rest of the batch.
                                std::thread::yield_now();
                            }
                        }
                        Err(RecvTimeoutError::Timeout) => {}
                        Err(RecvTimeoutError::Disconnected) => return encoder.finish(),
                    }
                    if flush.due() {
                        encoder.flush()?;
                    }
                }
            })?;
        Ok(Encoded {
            records,
            batch: Vec::with_capacity(BATCH),
            handed: Instant::now(),
            name,
            thread,
        })
    }

    /// Adds `record` to the batch, and hands the batch to the thread when it is full or
    /// its first record has waited [`BATCH_WAIT`]; a thread that stopped on an error says
    /// so at [`Encoded::finish`].
    fn send(&mut self, record: Record) {
        self.batch.push(record);
        if self.batch.len() >= BATCH || self.handed.elapsed() >= BATCH_WAIT {
            self.hand_over();
        }
    }

    fn hand_over(&mut self) {
        let batch = std::mem::replace(&mut self.batch, Vec::with_capacity(BATCH));
        // (A thread that stopped on an error says so at `finish`; a batch a lossy one has
        // no room for is dropped.)
        match &self.records {
            Handover::Lossless(records) => drop(records.send(batch)),
            Handover::Lossy(records) => drop(records.try_send(batch)),
        }
        self.handed = Instant::now();
    }

    /// The sink's opener of `run.mcap` in the run directory.
    pub fn open_mcap(run: &crate::RunStart) -> std::io::Result<Option<Box<dyn crate::Sink>>> {
        let file = McapFile::create(&run.dir.join("run.mcap"))?;
        Ok(Some(Box::new(Encoded::start(
            "run.mcap",
            file,
            run.scenario,
        )?)))
    }

    /// Waits for the thread to write everything and close its channels.
    pub fn finish(mut self) -> std::io::Result<()> {
        self.hand_over();
        drop(self.records);
        let name = self.name;
        self.thread
            .join()
            .map_err(|_| std::io::Error::other(format!("{name}: the writer thread panicked")))?
    }
}

impl crate::Sink for Encoded {
    fn sample(&mut self, sample: &crate::Sample<'_>) -> std::io::Result<()> {
        use crate::Sample;
        let record = match *sample {
            Sample::Tick(t) => Record::Tick(Box::new(TickRecord {
                truth: *t.truth,
                estimate: *t.estimate,
                actuation: *t.actuation,
                clearance_m: t.clearance_m,
                plant_input_latency_ns: t.measurement.map_or(0, |m| m.header.input_latency_ns),
            })),
            Sample::Plan(plan) => Record::Plan(Box::new(*plan)),
            Sample::Verdict(v) => Record::Verdict(*v),
            Sample::Route(route) if route.is_ok() => Record::Route(Box::new(*route)),
            Sample::Route(_) => return Ok(()),
            Sample::Tracks(tracks) => Record::Tracks(Box::new(*tracks)),
            Sample::Data(data) => Record::Data(Box::new(*data)),
        };
        self.send(record);
        Ok(())
    }

    fn event(&mut self, line: &crate::EventLine, json: &Value) -> std::io::Result<()> {
        self.send(Record::Event(Box::new((line.clone(), json.clone()))));
        Ok(())
    }

    fn end(self: Box<Self>, _summary: &crate::Summary, _whole: bool) -> std::io::Result<()> {
        self.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_covariance_ellipse_lies_along_the_principal_axes() {
        // Variance 4 along the diagonal x = y, 1 across it.
        let estimate = Estimate {
            covariance: [2.5, 1.5, 0.0, 1.5, 2.5, 0.0, 0.0, 0.0, 0.0],
            ..Estimate::default()
        };
        let ellipse = [covariance_ellipse(&estimate)];
        let scene = serde_json::to_value(SphereScene::new(0.0, "covariance", &ellipse)).unwrap();
        let sphere = &scene["entities"][0]["spheres"][0];
        let span = |axis: &str| sphere["size"][axis].as_f64().unwrap();
        assert!((span("x") - 2.0 * 3.0 * 2.0).abs() < 1e-12);
        assert!((span("y") - 2.0 * 3.0 * 1.0).abs() < 1e-12);
        let q = &sphere["pose"]["orientation"];
        let angle = 2.0 * q["z"].as_f64().unwrap().atan2(q["w"].as_f64().unwrap());
        assert!((angle - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
    }

    /// `message` written by hand and by serde_json.
    fn both(message: &(impl Json + Serialize)) -> (String, String) {
        let mut by_hand = Vec::new();
        message.write_json(&mut by_hand);
        let by_hand = String::from_utf8(by_hand).unwrap();
        (by_hand, serde_json::to_string(message).unwrap())
    }

    #[test]
    fn the_hand_written_messages_are_byte_for_byte_serde_jsons() {
        let numbers = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            0.1,
            1.0 / 3.0,
            1e-300,
            -4.9e-324,
            1.7976931348623157e308,
            123456789.125,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for (i, &a) in numbers.iter().enumerate() {
            let b = numbers[(i + 5) % numbers.len()];
            let c = numbers[(i + 9) % numbers.len()];
            let p = pose(a, b, c);
            let t = a.abs().min(1e9);
            let poses = [p, pose(c, a, b)];
            let estimate = EstimateRecord {
                tick: u64::MAX - i as u64,
                epoch: i as u32,
                x: a,
                y: b,
                theta: c,
                zeta: -a,
                covariance: std::array::from_fn(|k| numbers[(i + k) % numbers.len()]),
                position_sigma: b,
            };
            let command = CommandRecord {
                tick: i as u64,
                epoch: u32::MAX,
                u1: a,
                u2: b,
                v1: c,
                v2: -b,
                omega_r: -c,
                omega_l: a * 2.0,
                zeta: b / 3.0,
                mode: ["nominal", "say \"brake\"\n"][i % 2],
                mode_code: 7,
                plan_sample: u64::from(u32::MAX) + 1,
                deadline_misses: 0,
            };
            for (by_hand, by_serde) in [
                both(&PoseInFrame::new(t, p)),
                both(&PosesInFrame::new(t, &poses)),
                both(&PosesInFrame::new(t, &[])),
                both(&estimate),
                both(&command),
                both(&ClearanceRecord {
                    tick: i as u64,
                    clearance_m: a,
                }),
                both(&LatencyRecord {
                    tick: i as u64,
                    control_to_plant_us: c,
                    measurement_to_estimator_us: a,
                    estimate_to_dfl_us: b,
                }),
            ] {
                assert_eq!(by_hand, by_serde);
            }
        }
    }
}
