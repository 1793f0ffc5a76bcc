//! Foxglove's well-known schemas and this run's own, as JSON Schema, and the types their
//! messages are serialized from.

use super::*;

/// A time as Foxglove's schemas have it.
#[derive(Serialize)]
pub(super) struct Time {
    pub(super) sec: u64,
    pub(super) nsec: u64,
}

pub(super) fn timestamp(t: f64) -> Time {
    let ns = (t.max(0.0) * 1e9).round() as u64;
    Time {
        sec: ns / 1_000_000_000,
        nsec: ns % 1_000_000_000,
    }
}

#[derive(Serialize, Clone, Copy)]
pub(super) struct Vector3 {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) z: f64,
}

#[derive(Serialize, Clone, Copy)]
pub(super) struct Quaternion {
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) z: f64,
    pub(super) w: f64,
}

#[derive(Serialize, Clone, Copy)]
pub(super) struct Pose {
    pub(super) position: Vector3,
    pub(super) orientation: Quaternion,
}

/// A pose in the plane: at `(x, y)`, turned by `theta` about z.
pub(super) fn pose(x: f64, y: f64, theta: f64) -> Pose {
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
pub(super) struct PoseInFrame {
    pub(super) timestamp: Time,
    pub(super) frame_id: &'static str,
    pub(super) pose: Pose,
}

impl PoseInFrame {
    pub(super) fn new(t: f64, pose: Pose) -> PoseInFrame {
        PoseInFrame {
            timestamp: timestamp(t),
            frame_id: FRAME,
            pose,
        }
    }
}

/// `scmpc.Estimate`: the estimate as the estimator published it.
#[derive(Serialize)]
pub(super) struct EstimateRecord {
    pub(super) tick: u64,
    /// The producer epoch: which estimator process made it.
    pub(super) epoch: u32,
    pub(super) x: f64,
    pub(super) y: f64,
    pub(super) theta: f64,
    pub(super) zeta: f64,
    /// Of `[x, y, theta]`, row-major 3x3.
    pub(super) covariance: [f64; 9],
    pub(super) position_sigma: f64,
}

/// `scmpc.Command`: the DFL's command for one tick.
#[derive(Serialize)]
pub(super) struct CommandRecord {
    pub(super) tick: u64,
    pub(super) epoch: u32,
    pub(super) u1: f64,
    pub(super) u2: f64,
    pub(super) v1: f64,
    pub(super) v2: f64,
    pub(super) omega_r: f64,
    pub(super) omega_l: f64,
    pub(super) zeta: f64,
    pub(super) mode: &'static str,
    pub(super) mode_code: u32,
    pub(super) plan_sample: u64,
    pub(super) deadline_misses: u32,
}

/// `scmpc.Clearance`: the robot's clearance at a tick.
#[derive(Serialize)]
pub(super) struct ClearanceRecord {
    pub(super) tick: u64,
    /// From the robot's edge to the nearest obstacle's surface, m.
    pub(super) clearance_m: f64,
}

/// `scmpc.Latency`: the publish-to-receipt latency of the hops into a tick's command, µs
/// (0: not measured, as in process).
#[derive(Serialize)]
pub(super) struct LatencyRecord {
    pub(super) tick: u64,
    pub(super) control_to_plant_us: f64,
    pub(super) measurement_to_estimator_us: f64,
    pub(super) estimate_to_dfl_us: f64,
}

/// `scmpc.DeadlineVerdict`: the DFL's verdict on a sample.
#[derive(Serialize)]
pub(super) struct DeadlineRecord {
    pub(super) sample: u64,
    pub(super) met: bool,
    pub(super) status: &'static str,
    pub(super) production_us: f64,
    pub(super) arrival_ms: Option<f64>,
    pub(super) fallback: &'static str,
    pub(super) misses_total: u32,
}

/// `foxglove.PosesInFrame`.
#[derive(Serialize)]
pub(super) struct PosesInFrame<'a> {
    pub(super) timestamp: Time,
    pub(super) frame_id: &'static str,
    pub(super) poses: &'a [Pose],
}

impl PosesInFrame<'_> {
    pub(super) fn new(t: f64, poses: &[Pose]) -> PosesInFrame<'_> {
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
json_object!(ClearanceRecord { tick, clearance_m });
json_object!(LatencyRecord {
    tick,
    control_to_plant_us,
    measurement_to_estimator_us,
    estimate_to_dfl_us
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
pub(super) struct Color {
    pub(super) r: f64,
    pub(super) g: f64,
    pub(super) b: f64,
    pub(super) a: f64,
}

/// `foxglove.SpherePrimitive`.
#[derive(Serialize)]
pub(super) struct Sphere {
    pub(super) pose: Pose,
    pub(super) size: Vector3,
    pub(super) color: Color,
}

/// `foxglove.SceneUpdate` of one entity made of spheres, kept until replaced; the other
/// lists of Foxglove's schema are written empty (`[(); 0]` is `[]`).
#[derive(Serialize)]
pub(super) struct SphereScene<'a> {
    pub(super) deletions: [(); 0],
    pub(super) entities: [SphereEntity<'a>; 1],
}

impl SphereScene<'_> {
    pub(super) fn new<'a>(t: f64, id: &'static str, spheres: &'a [Sphere]) -> SphereScene<'a> {
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
pub(super) struct SphereEntity<'a> {
    pub(super) timestamp: Time,
    pub(super) frame_id: &'static str,
    pub(super) id: &'static str,
    pub(super) lifetime: Time,
    pub(super) frame_locked: bool,
    pub(super) metadata: [(); 0],
    pub(super) arrows: [(); 0],
    pub(super) cubes: [(); 0],
    pub(super) spheres: &'a [Sphere],
    pub(super) cylinders: [(); 0],
    pub(super) lines: [(); 0],
    pub(super) triangles: [(); 0],
    pub(super) texts: [(); 0],
    pub(super) models: [(); 0],
}

pub(super) fn color(r: f64, g: f64, b: f64, a: f64) -> Value {
    json!({ "r": r, "g": g, "b": b, "a": a })
}

/// A scene entity with only cylinders and spheres, kept until replaced (`lifetime` 0).
pub(super) fn entity(t: f64, id: &str, cylinders: Vec<Value>, spheres: Vec<Value>) -> Value {
    json!({
        "timestamp": timestamp(t), "frame_id": FRAME, "id": id,
        "lifetime": { "sec": 0, "nsec": 0 }, "frame_locked": false, "metadata": [],
        "arrows": [], "cubes": [], "spheres": spheres, "cylinders": cylinders,
        "lines": [], "triangles": [], "texts": [], "models": [],
    })
}

/// A flat disc (a cylinder) centred at `center`, of `radius`, `height` and colour `c`.
fn cylinder([x, y]: [f64; 2], radius: f64, height: f64, c: Value) -> Value {
    json!({
        "pose": pose(x, y, 0.0),
        "size": { "x": 2.0 * radius, "y": 2.0 * radius, "z": height },
        "bottom_scale": 1.0, "top_scale": 1.0, "color": c,
    })
}

/// The moving obstacles where they truly are at `t` (grey, as those at rest).
pub(super) fn moving_obstacles(t: f64, moving: &[protocol::Obstacle]) -> Value {
    let discs = moving
        .iter()
        .map(|o| {
            cylinder(
                o.center_at(t),
                o.radius,
                OBSTACLE_HEIGHT_M,
                color(0.45, 0.45, 0.45, 1.0),
            )
        })
        .collect();
    json!({ "deletions": [], "entities": [entity(t, "obstacles_moving", discs, vec![])] })
}

/// How a track's disc is predicted for the picture: `kappa`, the acceleration bound, and
/// the stages of a plan (as the MPC grows it, without the robot's own margins).
#[derive(Debug, Clone, Copy)]
pub(super) struct Prediction {
    kappa: f64,
    accel_max: f64,
    ts_s: f64,
    horizon: usize,
}

impl Prediction {
    pub(super) fn of(scenario: &Scenario) -> Prediction {
        Prediction {
            kappa: scenario.mpc.uncertainty_sigmas,
            accel_max: scenario.perception.accel_max,
            ts_s: scenario.timing.ts_s,
            horizon: scenario.mpc.horizon,
        }
    }
}

/// The tracker's tracks: each estimated disc (blue, grown by `kappa sigma_p`), and the
/// discs it predicts for the stages of a plan (faint blue; grown by
/// `kappa (sigma_p + t sigma_v) + accel_max t^2 / 2`, as the MPC's are before its own
/// margins).
pub(super) fn tracks_scene(tracks: &Tracks, p: &Prediction) -> Value {
    let t0 = tracks.header.time_s;
    let (mut estimated, mut predicted) = (Vec::new(), Vec::new());
    for track in tracks.tracks() {
        let (sigma_p, sigma_v) = track.sigmas();
        let blue = color(0.2, 0.4, 0.95, 0.8);
        estimated.push(cylinder(
            track.center,
            track.radius_m + p.kappa * sigma_p,
            OBSTACLE_HEIGHT_M,
            blue,
        ));
        for i in 1..=p.horizon {
            let t = i as f64 * p.ts_s;
            let center = [
                track.center[0] + track.velocity[0] * t,
                track.center[1] + track.velocity[1] * t,
            ];
            let radius =
                track.radius_m + p.kappa * (sigma_p + t * sigma_v) + 0.5 * p.accel_max * t * t;
            predicted.push(cylinder(
                center,
                radius,
                0.1 * OBSTACLE_HEIGHT_M,
                color(0.2, 0.4, 0.95, 0.15),
            ));
        }
    }
    json!({
        "deletions": [],
        "entities": [entity(t0, "tracks", estimated, vec![]), entity(t0, "predicted", predicted, vec![])],
    })
}

/// The obstacles at rest as they are (grey) and grown by the robot's radius and
/// `mpc.safety_margin_m` (translucent red; the MPC grows them further by `κσ`), the
/// start and the goal.
pub(super) fn world(scenario: &Scenario) -> Value {
    let grown_by = scenario.robot.radius_m + scenario.mpc.safety_margin_m;
    let disc = |o: &protocol::Obstacle, radius: f64, z: f64, c: Value| {
        json!({
            "pose": pose(o.x, o.y, 0.0),
            "size": { "x": 2.0 * radius, "y": 2.0 * radius, "z": z },
            "bottom_scale": 1.0, "top_scale": 1.0, "color": c,
        })
    };
    let at_rest = || scenario.obstacles.iter().filter(|o| !o.moves());
    let obstacles = at_rest()
        .map(|o| disc(o, o.radius, OBSTACLE_HEIGHT_M, color(0.45, 0.45, 0.45, 1.0)))
        .collect();
    let inflated = at_rest()
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
        marker(scenario.robot.goal.position, color(0.1, 0.7, 0.2, 1.0)),
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
pub(super) fn covariance_ellipse(estimate: &Estimate) -> Sphere {
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

pub(super) fn object(properties: Value) -> Value {
    json!({ "type": "object", "properties": properties })
}

pub(super) fn time_schema() -> Value {
    object(json!({ "sec": { "type": "integer" }, "nsec": { "type": "integer" } }))
}

pub(super) fn vector3_schema() -> Value {
    object(
        json!({ "x": { "type": "number" }, "y": { "type": "number" }, "z": { "type": "number" } }),
    )
}

pub(super) fn pose_schema() -> Value {
    object(json!({
        "position": vector3_schema(),
        "orientation": object(json!({
            "x": { "type": "number" }, "y": { "type": "number" },
            "z": { "type": "number" }, "w": { "type": "number" },
        })),
    }))
}

pub(super) fn pose_in_frame_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "pose": pose_schema(),
    }))
}

pub(super) fn laser_scan_schema() -> Value {
    let numbers = json!({ "type": "array", "items": { "type": "number" } });
    object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "pose": pose_schema(),
        "start_angle": { "type": "number" },
        "end_angle": { "type": "number" },
        "ranges": numbers,
        "intensities": numbers,
    }))
}

/// `foxglove.LaserScan`: a scan from `pose` (the lidar's, in the world), its beams from
/// `start_angle` to `end_angle` (rad, about the pose's z).
#[derive(Serialize)]
pub(super) struct LaserScan<'a> {
    pub(super) timestamp: Time,
    pub(super) frame_id: &'static str,
    pub(super) pose: Pose,
    pub(super) start_angle: f64,
    pub(super) end_angle: f64,
    pub(super) ranges: &'a [f64],
    pub(super) intensities: [f64; 0],
}

pub(super) fn poses_in_frame_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "frame_id": { "type": "string" },
        "poses": { "type": "array", "items": pose_schema() },
    }))
}

pub(super) fn scene_update_schema() -> Value {
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

pub(super) fn log_schema() -> Value {
    object(json!({
        "timestamp": time_schema(),
        "level": { "type": "integer" },
        "message": { "type": "string" },
        "name": { "type": "string" },
        "file": { "type": "string" },
        "line": { "type": "integer" },
    }))
}

pub(super) fn numbers(names: &[&str]) -> serde_json::Map<String, Value> {
    names
        .iter()
        .map(|n| (n.to_string(), json!({ "type": "number" })))
        .collect()
}

pub(super) fn estimate_schema() -> Value {
    let mut p = numbers(&["tick", "epoch", "x", "y", "theta", "zeta", "position_sigma"]);
    p.insert(
        "covariance".into(),
        json!({ "type": "array", "items": { "type": "number" } }),
    );
    object(Value::Object(p))
}

pub(super) fn command_schema() -> Value {
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

pub(super) fn clearance_schema() -> Value {
    object(json!({
        "tick": { "type": "integer" },
        "clearance_m": {
            "type": "number",
            "description": "from the robot's edge to the nearest obstacle's surface, m"
        },
    }))
}

pub(super) fn latency_schema() -> Value {
    let mut properties = numbers(&[
        "control_to_plant_us",
        "measurement_to_estimator_us",
        "estimate_to_dfl_us",
    ]);
    properties.insert("tick".into(), json!({ "type": "integer" }));
    object(Value::Object(properties))
}

pub(super) fn deadline_schema() -> Value {
    let mut p = numbers(&["sample", "production_us", "arrival_ms", "misses_total"]);
    p.insert("met".into(), json!({ "type": "boolean" }));
    p.insert("status".into(), json!({ "type": "string" }));
    p.insert("fallback".into(), json!({ "type": "string" }));
    object(Value::Object(p))
}
