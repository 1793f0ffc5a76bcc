//! `run.mcap`: the run for Foxglove (docs/foxglove.md).
//!
//! Messages are JSON with a JSON Schema. Channels whose schema is named after one of
//! Foxglove's well-known schemas (`foxglove.PoseInFrame`, `foxglove.PosesInFrame`,
//! `foxglove.SceneUpdate`, `foxglove.Log`) show in its 3D and log panels without
//! configuration; the `scmpc.*` channels carry the numbers for its plot panel. Every
//! message is logged at its simulated time, so the timeline is the run's clock.
//!
//! The writer lives in the orchestrator, on a thread of its own: the recorder hands it
//! copies of the messages ([`McapLog`]), and the thread encodes and writes them, so the
//! recording costs the orchestrator's loop a copy per message. The messages of every tick
//! and plan are encoded by hand ([`super::json`]), the rest by serde_json, to the same
//! bytes.

use super::json::{Json, json_object};
use protocol::{
    Actuation, CommandMode, DeadlineVerdict, Estimate, GroundTruth, PLAN_MISSING, Plan, PlanStatus,
    Route, Scenario, Timing,
};
use serde::Serialize;
use serde_json::{Value, json};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

/// A channel of `run.mcap`: topic, schema name, JSON Schema.
type Channel = (&'static str, &'static str, fn() -> Value);

/// Every channel of `run.mcap`.
const CHANNELS: [Channel; 10] = [
    (
        "/world/obstacles",
        "foxglove.SceneUpdate",
        scene_update_schema,
    ),
    ("/robot/truth", "foxglove.PoseInFrame", pose_in_frame_schema),
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
    ("/dfl/deadline", "scmpc.DeadlineVerdict", deadline_schema),
    ("/events", "foxglove.Log", log_schema),
];

/// The frame every pose is given in: the scenario's plane, z up.
const FRAME: &str = "world";
/// Height of the obstacle cylinders, m (the world is planar).
const OBSTACLE_HEIGHT_M: f64 = 0.3;
/// The covariance ellipse spans this many standard deviations each way.
const COVARIANCE_SIGMAS: f64 = 3.0;

/// What the recorder hands the writer thread.
enum Record {
    Tick(Box<(GroundTruth, Estimate, Actuation)>),
    Plan(Box<Plan>),
    Route(Box<Route>),
    Verdict(DeadlineVerdict),
    Event(f64, String, Value),
}

/// `run.mcap` being written by its thread.
pub struct McapLog {
    records: std::sync::mpsc::Sender<Vec<Record>>,
    /// Records not handed over yet: the thread gets them in batches, so it wakes once per
    /// batch rather than once per message (in lockstep, thousands of times a second).
    batch: Vec<Record>,
    handed: Instant,
    thread: std::thread::JoinHandle<std::io::Result<()>>,
}

/// Records per batch, and the longest a record waits for its batch.
const BATCH: usize = 64;
const BATCH_WAIT: Duration = Duration::from_millis(100);

impl McapLog {
    /// Creates `path` with every channel and the world at time 0, and starts the thread
    /// that writes the rest.
    pub fn create(path: &Path, scenario: &Scenario) -> std::io::Result<McapLog> {
        let mut file = McapFile::create(path, scenario)?;
        let (records, received) = std::sync::mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("run.mcap".into())
            .spawn(move || {
                let mut flush = super::FlushClock::new();
                loop {
                    match received.recv_timeout(super::FLUSH_PERIOD) {
                        Ok(batch) => {
                            for record in batch {
                                file.record(record)?;
                                // In lockstep every core runs a role polling for its
                                // input (yielding between polls): give the core back after
                                // each record, so that the role whose input came runs at
                                // once, not after the rest of the batch.
                                std::thread::yield_now();
                            }
                        }
                        Err(RecvTimeoutError::Timeout) => {}
                        Err(RecvTimeoutError::Disconnected) => return file.finish(),
                    }
                    if flush.due() {
                        file.flush()?;
                    }
                }
            })?;
        Ok(McapLog {
            records,
            batch: Vec::with_capacity(BATCH),
            handed: Instant::now(),
            thread,
        })
    }

    /// Adds `record` to the batch, and hands the batch to the thread when it is full or
    /// its first record has waited [`BATCH_WAIT`]; a thread that stopped on an error says
    /// so at [`McapLog::finish`].
    fn send(&mut self, record: Record) {
        self.batch.push(record);
        if self.batch.len() >= BATCH || self.handed.elapsed() >= BATCH_WAIT {
            self.hand_over();
        }
    }

    fn hand_over(&mut self) {
        let batch = std::mem::replace(&mut self.batch, Vec::with_capacity(BATCH));
        let _ = self.records.send(batch);
        self.handed = Instant::now();
    }

    pub fn tick(&mut self, truth: &GroundTruth, estimate: &Estimate, act: &Actuation) {
        self.send(Record::Tick(Box::new((*truth, *estimate, *act))));
    }

    pub fn plan(&mut self, plan: &Plan) {
        self.send(Record::Plan(Box::new(*plan)));
    }

    pub fn route(&mut self, route: &Route) {
        self.send(Record::Route(Box::new(*route)));
    }

    pub fn verdict(&mut self, v: &DeadlineVerdict) {
        self.send(Record::Verdict(*v));
    }

    pub fn event(&mut self, t: f64, event: &str, line: &Value) {
        self.send(Record::Event(t, event.to_string(), line.clone()));
    }

    /// Waits for the thread to write everything and close the file.
    pub fn finish(mut self) -> std::io::Result<()> {
        self.hand_over();
        drop(self.records);
        self.thread
            .join()
            .map_err(|_| std::io::Error::other("run.mcap: the writer thread panicked"))?
    }
}

/// An open `run.mcap`.
struct McapFile {
    writer: mcap::Writer<BufWriter<File>>,
    channels: BTreeMap<&'static str, u16>,
    sequence: u32,
    timing: Timing,
    /// Reused for every message: its JSON, and a plan's or a route's poses.
    json: Vec<u8>,
    poses: Vec<Pose>,
}

/// An error of the MCAP writer, as an I/O error (the recorder's).
fn io(e: mcap::McapError) -> std::io::Error {
    std::io::Error::other(format!("run.mcap: {e}"))
}

impl McapFile {
    /// Creates `path` with every channel, and logs the world at time 0.
    fn create(path: &Path, scenario: &Scenario) -> std::io::Result<McapFile> {
        let file = BufWriter::new(File::create(path)?);
        // Chunks are kept in memory until whole (no seeking back to patch a chunk's
        // length), so a chunk on disk is a whole record: a run killed mid-chunk leaves a
        // file whose records read in order up to the last flush.
        let mut writer = mcap::WriteOptions::new()
            .disable_seeking(true)
            .profile("")
            .library(concat!("scmpc ", env!("CARGO_PKG_VERSION")))
            .create(file)
            .map_err(io)?;
        let mut channels = BTreeMap::new();
        for (topic, schema_name, schema) in CHANNELS {
            let schema = serde_json::to_vec(&schema()).map_err(std::io::Error::other)?;
            let schema_id = writer
                .add_schema(schema_name, "jsonschema", &schema)
                .map_err(io)?;
            let channel = writer
                .add_channel(schema_id, topic, "json", &BTreeMap::new())
                .map_err(io)?;
            channels.insert(topic, channel);
        }
        let mut log = McapFile {
            writer,
            channels,
            sequence: 0,
            timing: scenario.timing.clone(),
            json: Vec::with_capacity(4096),
            poses: Vec::with_capacity(protocol::MAX_HORIZON + 1),
        };
        log.write_serde("/world/obstacles", 0.0, &world(scenario))?;
        Ok(log)
    }

    fn record(&mut self, record: Record) -> std::io::Result<()> {
        match record {
            Record::Tick(tick) => self.tick(&tick.0, &tick.1, &tick.2),
            Record::Plan(plan) => self.plan(&plan),
            Record::Route(route) => self.route(&route),
            Record::Verdict(v) => self.verdict(&v),
            Record::Event(t, event, line) => self.event(t, &event, &line),
        }
    }

    /// Closes the chunk being written and hands it to the file system: a reader that scans
    /// records in order reads everything up to here, whatever happens to the run after.
    fn flush(&mut self) -> std::io::Result<()> {
        self.writer.flush().map_err(io)
    }

    /// Writes a message of the ticks and plans ([`Json`]).
    fn write(&mut self, topic: &str, time_s: f64, message: &impl Json) -> std::io::Result<()> {
        self.json.clear();
        message.write_json(&mut self.json);
        self.write_encoded(topic, time_s)
    }

    /// Writes any other message, with serde.
    fn write_serde(
        &mut self,
        topic: &str,
        time_s: f64,
        message: &impl Serialize,
    ) -> std::io::Result<()> {
        self.json.clear();
        serde_json::to_writer(&mut self.json, message).map_err(std::io::Error::other)?;
        self.write_encoded(topic, time_s)
    }

    /// Writes the message encoded in `json` on `topic`'s channel.
    fn write_encoded(&mut self, topic: &str, time_s: f64) -> std::io::Result<()> {
        let channel_id = self.channels[topic];
        let time_ns = (time_s.max(0.0) * 1e9).round() as u64;
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: time_ns,
            publish_time: time_ns,
        };
        self.writer
            .write_to_known_channel(&header, &self.json)
            .map_err(io)
    }

    /// One inner tick: the true and estimated poses, the estimate and the command applied;
    /// at every sample's first tick, the estimate's covariance ellipse.
    fn tick(
        &mut self,
        truth: &GroundTruth,
        estimate: &Estimate,
        act: &Actuation,
    ) -> std::io::Result<()> {
        let t = truth.header.time_s;
        let [x, y, theta] = truth.pose;
        self.write("/robot/truth", t, &PoseInFrame::new(t, pose(x, y, theta)))?;
        let [xh, yh, thetah, zeta] = estimate.state;
        self.write(
            "/robot/estimate",
            t,
            &PoseInFrame::new(t, pose(xh, yh, thetah)),
        )?;
        if self.timing.starts_sample(truth.header.tick) {
            let ellipse = [covariance_ellipse(estimate)];
            self.write_serde(
                "/robot/covariance",
                t,
                &SphereScene::new(t, "covariance", &ellipse),
            )?;
        }
        let record = EstimateRecord {
            tick: estimate.header.tick,
            epoch: estimate.header.epoch,
            x: xh,
            y: yh,
            theta: thetah,
            zeta,
            covariance: estimate.covariance,
            position_sigma: estimate.position_sigma(),
        };
        self.write("/estimator/estimate", t, &record)?;
        let command = CommandRecord {
            tick: act.header.tick,
            epoch: act.header.epoch,
            u1: act.u1,
            u2: act.u2,
            v1: act.v[0],
            v2: act.v[1],
            omega_r: act.wheels[0],
            omega_l: act.wheels[1],
            zeta: act.zeta,
            mode: act.mode().map_or("unknown", CommandMode::as_str),
            mode_code: act.mode,
            plan_sample: act.plan_sample,
            deadline_misses: act.deadline_misses,
        };
        self.write("/dfl/command", t, &command)
    }

    /// A plan as published: its predicted positions, each headed along its velocity.
    fn plan(&mut self, plan: &Plan) -> std::io::Result<()> {
        let t = plan.header.time_s;
        let n = (plan.horizon as usize).min(protocol::MAX_HORIZON);
        let mut poses = std::mem::take(&mut self.poses);
        poses.clear();
        poses.extend(
            (plan.z[..=n].iter()).map(|[x, xdot, y, ydot]| pose(*x, *y, ydot.atan2(*xdot))),
        );
        let written = self.write("/mpc/plan", t, &PosesInFrame::new(t, &poses));
        self.poses = poses;
        written
    }

    /// A new route of the planner.
    fn route(&mut self, route: &Route) -> std::io::Result<()> {
        let t = route.header.time_s;
        let points = route.points();
        let poses: Vec<Pose> = points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                // Headed along the segment it starts (the goal: the one it ends).
                let (from, to) = match points.get(i + 1) {
                    Some(next) => (p, next),
                    None => (&points[i.saturating_sub(1)], p),
                };
                pose(p[0], p[1], (to[1] - from[1]).atan2(to[0] - from[0]))
            })
            .collect();
        self.write("/planner/route", t, &PosesInFrame::new(t, &poses))
    }

    /// The DFL's deadline verdict on a sample.
    fn verdict(&mut self, v: &DeadlineVerdict) -> std::io::Result<()> {
        let status = match v.status {
            PLAN_MISSING => "missing",
            code => PlanStatus::from_code(code).map_or("unknown", PlanStatus::as_str),
        };
        let fallback = CommandMode::from_code(v.fallback).map_or("unknown", CommandMode::as_str);
        let record = DeadlineRecord {
            sample: v.sample,
            met: v.met != 0,
            status,
            production_us: v.production_ns as f64 / 1e3,
            arrival_ms: (v.arrival_ns != u64::MAX).then(|| v.arrival_ns as f64 / 1e6),
            fallback,
            misses_total: v.misses_total,
        };
        self.write_serde("/dfl/deadline", v.header.time_s, &record)
    }

    /// An event of `events.jsonl` (`line`: its whole JSON line) as a log message: warnings
    /// for what went wrong, information otherwise.
    fn event(&mut self, t: f64, event: &str, line: &Value) -> std::io::Result<()> {
        const INFO: u8 = 2;
        const WARNING: u8 = 3;
        let warning = [
            "deadline_miss",
            "safety_intervention",
            "died",
            "restarted",
            "rejected",
            "input_lost",
            "no_route",
            "swap_refused",
        ];
        let level = if warning.iter().any(|w| event.starts_with(w)) {
            WARNING
        } else {
            INFO
        };
        self.write_serde(
            "/events",
            t,
            &json!({
                "timestamp": timestamp(t),
                "level": level,
                "message": line.to_string(),
                "name": event,
                "file": "events.jsonl",
                "line": 0,
            }),
        )
    }

    fn finish(mut self) -> std::io::Result<()> {
        self.writer.finish().map(|_| ()).map_err(io)
    }
}

/// A time as Foxglove's schemas have it.
#[derive(Serialize)]
struct Time {
    sec: u64,
    nsec: u64,
}

fn timestamp(t: f64) -> Time {
    let ns = (t.max(0.0) * 1e9).round() as u64;
    Time {
        sec: ns / 1_000_000_000,
        nsec: ns % 1_000_000_000,
    }
}

#[derive(Serialize, Clone, Copy)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize, Clone, Copy)]
struct Quaternion {
    x: f64,
    y: f64,
    z: f64,
    w: f64,
}

#[derive(Serialize, Clone, Copy)]
struct Pose {
    position: Vector3,
    orientation: Quaternion,
}

/// A pose in the plane: at `(x, y)`, turned by `theta` about z.
fn pose(x: f64, y: f64, theta: f64) -> Pose {
    let half = 0.5 * theta;
    Pose {
        position: Vector3 { x, y, z: 0.0 },
        orientation: Quaternion {
            x: 0.0,
            y: 0.0,
            z: half.sin(),
            w: half.cos(),
        },
    }
}

/// `foxglove.PoseInFrame`.
#[derive(Serialize)]
struct PoseInFrame {
    timestamp: Time,
    frame_id: &'static str,
    pose: Pose,
}

impl PoseInFrame {
    fn new(t: f64, pose: Pose) -> PoseInFrame {
        PoseInFrame {
            timestamp: timestamp(t),
            frame_id: FRAME,
            pose,
        }
    }
}

/// `scmpc.Estimate`: the estimate as the estimator published it.
#[derive(Serialize)]
struct EstimateRecord {
    tick: u64,
    /// The producer epoch: which estimator process made it.
    epoch: u32,
    x: f64,
    y: f64,
    theta: f64,
    zeta: f64,
    /// Of `[x, y, theta]`, row-major 3x3.
    covariance: [f64; 9],
    position_sigma: f64,
}

/// `scmpc.Command`: the DFL's command for one tick.
#[derive(Serialize)]
struct CommandRecord {
    tick: u64,
    epoch: u32,
    u1: f64,
    u2: f64,
    v1: f64,
    v2: f64,
    omega_r: f64,
    omega_l: f64,
    zeta: f64,
    mode: &'static str,
    mode_code: u32,
    plan_sample: u64,
    deadline_misses: u32,
}

/// `scmpc.DeadlineVerdict`: the DFL's verdict on a sample.
#[derive(Serialize)]
struct DeadlineRecord {
    sample: u64,
    met: bool,
    status: &'static str,
    production_us: f64,
    arrival_ms: Option<f64>,
    fallback: &'static str,
    misses_total: u32,
}

/// `foxglove.PosesInFrame`.
#[derive(Serialize)]
struct PosesInFrame<'a> {
    timestamp: Time,
    frame_id: &'static str,
    poses: &'a [Pose],
}

impl PosesInFrame<'_> {
    fn new(t: f64, poses: &[Pose]) -> PosesInFrame<'_> {
        PosesInFrame {
            timestamp: timestamp(t),
            frame_id: FRAME,
            poses,
        }
    }
}

json_object!(Time { sec, nsec });
json_object!(Vector3 { x, y, z });
json_object!(Quaternion { x, y, z, w });
json_object!(Pose {
    position,
    orientation
});
json_object!(PoseInFrame {
    timestamp,
    frame_id,
    pose
});
json_object!(PosesInFrame<'_> {
    timestamp,
    frame_id,
    poses
});
json_object!(EstimateRecord {
    tick,
    epoch,
    x,
    y,
    theta,
    zeta,
    covariance,
    position_sigma
});
json_object!(CommandRecord {
    tick,
    epoch,
    u1,
    u2,
    v1,
    v2,
    omega_r,
    omega_l,
    zeta,
    mode,
    mode_code,
    plan_sample,
    deadline_misses
});

#[derive(Serialize, Clone, Copy)]
struct Color {
    r: f64,
    g: f64,
    b: f64,
    a: f64,
}

/// `foxglove.SpherePrimitive`.
#[derive(Serialize)]
struct Sphere {
    pose: Pose,
    size: Vector3,
    color: Color,
}

/// `foxglove.SceneUpdate` of one entity made of spheres, kept until replaced; the other
/// lists of Foxglove's schema are written empty (`[(); 0]` is `[]`).
#[derive(Serialize)]
struct SphereScene<'a> {
    deletions: [(); 0],
    entities: [SphereEntity<'a>; 1],
}

impl SphereScene<'_> {
    fn new<'a>(t: f64, id: &'static str, spheres: &'a [Sphere]) -> SphereScene<'a> {
        SphereScene {
            deletions: [],
            entities: [SphereEntity {
                timestamp: timestamp(t),
                frame_id: FRAME,
                id,
                lifetime: timestamp(0.0),
                frame_locked: false,
                metadata: [],
                arrows: [],
                cubes: [],
                spheres,
                cylinders: [],
                lines: [],
                triangles: [],
                texts: [],
                models: [],
            }],
        }
    }
}

#[derive(Serialize)]
struct SphereEntity<'a> {
    timestamp: Time,
    frame_id: &'static str,
    id: &'static str,
    lifetime: Time,
    frame_locked: bool,
    metadata: [(); 0],
    arrows: [(); 0],
    cubes: [(); 0],
    spheres: &'a [Sphere],
    cylinders: [(); 0],
    lines: [(); 0],
    triangles: [(); 0],
    texts: [(); 0],
    models: [(); 0],
}

fn color(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({ "r": r, "g": g, "b": b, "a": a })
}

/// A scene entity with only cylinders and spheres, kept until replaced (`lifetime` 0).
fn entity(t: f64, id: &str, cylinders: Vec<Value>, spheres: Vec<Value>) -> Value {
    json!({
        "timestamp": timestamp(t), "frame_id": FRAME, "id": id,
        "lifetime": { "sec": 0, "nsec": 0 }, "frame_locked": false, "metadata": [],
        "arrows": [], "cubes": [], "spheres": spheres, "cylinders": cylinders,
        "lines": [], "triangles": [], "texts": [], "models": [],
    })
}

/// The obstacles as they are (grey) and grown by the robot's radius and
/// `mpc.safety_margin_m` (translucent red; the MPC grows them further by `κσ`), the
/// start and the goal.
fn world(scenario: &Scenario) -> Value {
    let grown_by = scenario.robot.radius_m + scenario.mpc.safety_margin_m;
    let disc = |o: &protocol::Obstacle, radius: f64, z: f64, c: Value| {
        json!({
            "pose": pose(o.x, o.y, 0.0),
            "size": { "x": 2.0 * radius, "y": 2.0 * radius, "z": z },
            "bottom_scale": 1.0, "top_scale": 1.0, "color": c,
        })
    };
    let obstacles = scenario
        .obstacles
        .iter()
        .map(|o| disc(o, o.radius, OBSTACLE_HEIGHT_M, color(0.45, 0.45, 0.45, 1.0)))
        .collect();
    let inflated = scenario
        .obstacles
        .iter()
        .map(|o| {
            disc(
                o,
                o.radius + grown_by,
                0.5 * OBSTACLE_HEIGHT_M,
                color(0.9, 0.2, 0.2, 0.3),
            )
        })
        .collect();
    let marker = |[x, y]: [f64; 2], c: Value| json!({ "pose": pose(x, y, 0.0), "size": { "x": 0.2, "y": 0.2, "z": 0.2 }, "color": c });
    let [sx, sy, _] = scenario.robot.start;
    let ends = vec![
        marker([sx, sy], color(0.1, 0.4, 0.9, 1.0)),
        marker(scenario.robot.goal, color(0.1, 0.7, 0.2, 1.0)),
    ];
    json!({
        "deletions": [],
        "entities": [
            entity(0.0, "obstacles", obstacles, vec![]),
            entity(0.0, "obstacles_inflated", inflated, vec![]),
            entity(0.0, "start_goal", vec![], ends),
        ],
    })
}

/// The `COVARIANCE_SIGMAS` ellipse of the estimate's position covariance, as a flat
/// sphere along the covariance's principal axes.
fn covariance_ellipse(estimate: &Estimate) -> Sphere {
    let c = &estimate.covariance;
    let (a, b, d) = (c[0], 0.5 * (c[1] + c[3]), c[4]);
    let mean = 0.5 * (a + d);
    let spread = (0.25 * (a - d).powi(2) + b * b).sqrt();
    let (major, minor) = ((mean + spread).max(0.0), (mean - spread).max(0.0));
    let angle = 0.5 * (2.0 * b).atan2(a - d);
    let [x, y, ..] = estimate.state;
    let span = |variance: f64| 2.0 * COVARIANCE_SIGMAS * variance.sqrt();
    Sphere {
        pose: pose(x, y, angle),
        size: Vector3 {
            x: span(major),
            y: span(minor),
            z: 0.01,
        },
        color: Color {
            r: 0.2,
            g: 0.4,
            b: 1.0,
            a: 0.35,
        },
    }
}

// JSON Schemas of the channels. The `foxglove.*` ones describe the fields written here of
// Foxglove's schemas of those names.

fn object(properties: Value) -> Value {
    json!({ "type": "object", "properties": properties })
}

fn time_schema() -> Value {
    object(json!({ "sec": { "type": "integer" }, "nsec": { "type": "integer" } }))
}

fn vector3_schema() -> Value {
    object(
        json!({ "x": { "type": "number" }, "y": { "type": "number" }, "z": { "type": "number" } }),
    )
}

fn pose_schema() -> Value {
    object(json!({
        "position": vector3_schema(),
        "orientation": object(json!({
            "x": { "type": "number" }, "y": { "type": "number" },
            "z": { "type": "number" }, "w": { "type": "number" },
        })),
    }))
}

fn pose_in_frame_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "pose": pose_schema(),
    }))
}

fn poses_in_frame_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "poses": { "type": "array", "items": pose_schema() },
    }))
}

fn scene_update_schema() -> Value {
    let colour = object(json!({
        "r": { "type": "number" }, "g": { "type": "number" },
        "b": { "type": "number" }, "a": { "type": "number" },
    }));
    let primitive =
        object(json!({ "pose": pose_schema(), "size": vector3_schema(), "color": colour }));
    let list = |items: Value| json!({ "type": "array", "items": items });
    let entity = object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "id": { "type": "string" },
        "lifetime": time_schema(),
        "frame_locked": { "type": "boolean" },
        "metadata": list(json!({})),
        "arrows": list(json!({})),
        "cubes": list(json!({})),
        "spheres": list(primitive.clone()),
        "cylinders": list(primitive),
        "lines": list(json!({})),
        "triangles": list(json!({})),
        "texts": list(json!({})),
        "models": list(json!({})),
    }));
    object(json!({ "deletions": list(json!({})), "entities": list(entity) }))
}

fn log_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "level": { "type": "integer" },
        "message": { "type": "string" },
        "name": { "type": "string" },
        "file": { "type": "string" },
        "line": { "type": "integer" },
    }))
}

fn numbers(names: &[&str]) -> serde_json::Map<String, Value> {
    names
        .iter()
        .map(|n| (n.to_string(), json!({ "type": "number" })))
        .collect()
}

fn estimate_schema() -> Value {
    let mut p = numbers(&["tick", "epoch", "x", "y", "theta", "zeta", "position_sigma"]);
    p.insert(
        "covariance".into(),
        json!({ "type": "array", "items": { "type": "number" } }),
    );
    object(Value::Object(p))
}

fn command_schema() -> Value {
    let mut p = numbers(&[
        "tick",
        "epoch",
        "u1",
        "u2",
        "v1",
        "v2",
        "omega_r",
        "omega_l",
        "zeta",
        "mode_code",
        "plan_sample",
        "deadline_misses",
    ]);
    p.insert("mode".into(), json!({ "type": "string" }));
    object(Value::Object(p))
}

fn deadline_schema() -> Value {
    let mut p = numbers(&["sample", "production_us", "arrival_ms", "misses_total"]);
    p.insert("met".into(), json!({ "type": "boolean" }));
    p.insert("status".into(), json!({ "type": "string" }));
    p.insert("fallback".into(), json!({ "type": "string" }));
    object(Value::Object(p))
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
            ] {
                assert_eq!(by_hand, by_serde);
            }
        }
    }
}
