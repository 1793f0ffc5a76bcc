//! The encoder: every message of a run as JSON on its channel, whatever the channels
//! are written to ([`Channels`]: `run.mcap`, a live view).

use super::foxglove::*;
use super::*;

/// The messages of a run as JSON, on their channels in `out`.
pub(super) struct Encoder<C> {
    out: C,
    /// Reused for a [`Record::Data`]'s values.
    values: Vec<f64>,
    timing: Timing,
    /// Reused for every message: its JSON, and a plan's or a route's poses.
    json: Vec<u8>,
    poses: Vec<Pose>,
    /// The obstacles that move: their true positions are logged every tick.
    moving: Vec<protocol::Obstacle>,
    /// How a track's predicted disc grows ([`foxglove::tracks`]).
    prediction: Prediction,
    /// The robot's newest true poses by tick, to place a scan taken at one of them.
    truths: std::collections::VecDeque<(u64, [f64; 3])>,
    /// Reused for a scan's ranges.
    ranges: Vec<f64>,
    /// Scans whose robot pose is not recorded yet (a tick's samples come after the
    /// scan of its perception tick).
    scans: std::collections::VecDeque<Box<protocol::Scan>>,
}

/// True poses kept to place the scans: more than a scan's age ([`protocol::Scan::age_ticks`]).
const TRUTHS_KEPT: usize = 128;

/// The channel of a topic the record has no place of its own for: `/<producer>/<topic>`.
fn data_channel(topic: &str) -> String {
    let producer = protocol::graph::producer_of(topic).map_or("unknown", |r| r.as_str());
    format!("/{producer}/{topic}")
}

/// A channel for each topic of `scenario`'s graph that the record has no place of its
/// own for and whose type names what to record ([`protocol::Message::RECORDED`]): its
/// schema, `scmpc.<Type>`, an object of its time, its tick and those values.
fn data_channels(scenario: &Scenario) -> Vec<(String, String, Value)> {
    let graph = protocol::graph::Graph::of(scenario);
    graph
        .recorded()
        .map(|topic| {
            let mut properties = serde_json::Map::new();
            properties.insert(
                "t".into(),
                json!({ "type": "number", "description": "simulated time, s" }),
            );
            properties.insert("tick".into(), json!({ "type": "integer" }));
            for name in protocol::Data::recorded_names(topic.name) {
                properties.insert((*name).into(), json!({ "type": "number" }));
            }
            let schema = json!({
                "type": "object",
                "properties": properties,
                "required": properties.keys().collect::<Vec<_>>(),
            });
            let name = topic.message.replace("::", ".");
            (data_channel(topic.name), name, schema)
        })
        .collect()
}

impl<C: Channels> Encoder<C> {
    /// Adds every channel of `scenario`'s run to `out`, and logs the world at time 0.
    pub(super) fn new(mut out: C, scenario: &Scenario) -> std::io::Result<Encoder<C>> {
        let recorded = data_channels(scenario);
        let all = CHANNELS
            .iter()
            .filter(|(topic, ..)| carries(topic, scenario))
            .map(|(topic, name, schema)| (topic.to_string(), name.to_string(), schema()))
            .chain(recorded);
        for (topic, schema_name, schema) in all {
            let schema = serde_json::to_vec(&schema).map_err(std::io::Error::other)?;
            out.add_channel(&topic, &schema_name, &schema)?;
        }
        let mut log = Encoder {
            out,
            values: Vec::new(),
            timing: scenario.timing.clone(),
            json: Vec::with_capacity(4096),
            poses: Vec::with_capacity(protocol::MAX_HORIZON + 1),
            moving: scenario
                .obstacles
                .iter()
                .filter(|o| o.moves())
                .cloned()
                .collect(),
            prediction: Prediction::of(scenario),
            truths: std::collections::VecDeque::with_capacity(TRUTHS_KEPT),
            ranges: Vec::with_capacity(protocol::MAX_BEAMS),
            scans: std::collections::VecDeque::new(),
        };
        log.write_serde("/world/obstacles", 0.0, &world(scenario))?;
        Ok(log)
    }

    pub(super) fn record(&mut self, record: Record) -> std::io::Result<()> {
        match record {
            Record::Tick(tick) => self.tick(&tick),
            Record::Plan(plan) => self.plan(&plan),
            Record::Route(route) => self.route(&route),
            Record::Tracks(tracks) => {
                let t = tracks.header.time_s;
                self.write_serde(
                    "/tracker/tracks",
                    t,
                    &tracks_scene(&tracks, &self.prediction),
                )
            }
            Record::Verdict(v) => self.verdict(&v),
            Record::Event(event) => self.event(&event.0, &event.1),
            Record::Data(data) => self.data(&data),
        }
    }

    /// A message of a topic the record has no place of its own for, on its channel
    /// ([`data_channels`]): its time, its tick and the values its type names.
    fn data(&mut self, data: &protocol::Data) -> std::io::Result<()> {
        let header = data.header();
        self.values.clear();
        data.recorded(&mut self.values);
        let mut message = serde_json::Map::new();
        message.insert("t".into(), json!(header.time_s));
        message.insert("tick".into(), json!(header.tick));
        let names = protocol::Data::recorded_names(data.topic());
        for (name, value) in names.iter().zip(&self.values) {
            message.insert((*name).into(), json!(value));
        }
        self.write_serde(&data_channel(data.topic()), header.time_s, &message)?;
        if let protocol::Data::Scan(scan) = data {
            self.scans.push_back(Box::new(*scan));
            self.placed_scans(false)?;
        }
        Ok(())
    }

    /// The scans waiting whose robot pose is recorded (`all`: every one, at the newest
    /// pose recorded, at the end), as `foxglove.LaserScan`s.
    fn placed_scans(&mut self, all: bool) -> std::io::Result<()> {
        let newest = self.truths.back().map(|(tick, _)| *tick);
        while let Some(taken) = self.scans.front().map(|s| s.taken_tick()) {
            if !all && newest.is_none_or(|newest| newest < taken) {
                break;
            }
            if let Some(scan) = self.scans.pop_front() {
                self.scan(&scan, taken)?;
            }
        }
        Ok(())
    }

    /// A scan taken at tick `taken`, from where the robot truly was then (the newest true
    /// pose recorded before, if that one is not); a beam with no return is written 0 m
    /// (JSON has no infinity), a point at the lidar.
    fn scan(&mut self, scan: &protocol::Scan, taken: u64) -> std::io::Result<()> {
        let robot = (self.truths.iter().rev())
            .find(|(tick, _)| *tick <= taken)
            .or(self.truths.back())
            .map_or([0.0; 3], |(_, pose)| *pose);
        let [x, y, theta] = protocol::mounted(robot, scan.offset);
        self.ranges.clear();
        (self.ranges).extend(
            scan.ranges()
                .iter()
                .map(|&r| if r.is_finite() { f64::from(r) } else { 0.0 }),
        );
        let t = scan.header.time_s;
        let last = scan.beams.saturating_sub(1) as usize;
        let message = LaserScan {
            timestamp: timestamp(t),
            frame_id: FRAME,
            pose: pose(x, y, theta),
            start_angle: scan.angle_min_rad,
            end_angle: scan.angle_rad(last),
            ranges: &self.ranges,
            intensities: [],
        };
        self.json.clear();
        serde_json::to_writer(&mut self.json, &message).map_err(std::io::Error::other)?;
        self.write_encoded("/lidar/laser_scan", t)
    }

    pub(super) fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    /// Writes a message of the ticks and plans ([`Json`]).
    pub(super) fn write(
        &mut self,
        topic: &str,
        time_s: f64,
        message: &impl Json,
    ) -> std::io::Result<()> {
        self.json.clear();
        message.write_json(&mut self.json);
        self.write_encoded(topic, time_s)
    }

    /// Writes any other message, with serde.
    pub(super) fn write_serde(
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
    pub(super) fn write_encoded(&mut self, topic: &str, time_s: f64) -> std::io::Result<()> {
        let time_ns = (time_s.max(0.0) * 1e9).round() as u64;
        self.out.message(topic, time_ns, &self.json)
    }

    /// One inner tick: the true and estimated poses, the estimate, the command applied, the
    /// clearance and the hops' latencies; at every sample's first tick, the estimate's
    /// covariance ellipse.
    pub(super) fn tick(&mut self, tick: &TickRecord) -> std::io::Result<()> {
        let (truth, estimate, act) = (&tick.truth, &tick.estimate, &tick.actuation);
        let t = truth.header.time_s;
        let [x, y, theta] = truth.pose;
        self.write("/robot/truth", t, &PoseInFrame::new(t, pose(x, y, theta)))?;
        if self.truths.len() == TRUTHS_KEPT {
            self.truths.pop_front();
        }
        self.truths.push_back((truth.header.tick, truth.pose));
        self.placed_scans(false)?;
        if !self.moving.is_empty() {
            self.write_serde(
                "/world/moving_obstacles",
                t,
                &moving_obstacles(t, &self.moving),
            )?;
        }
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
        self.write("/dfl/command", t, &command)?;
        let clearance = ClearanceRecord {
            tick: truth.header.tick,
            clearance_m: tick.clearance_m,
        };
        self.write("/robot/clearance", t, &clearance)?;
        let us = |ns: u32| f64::from(ns) / 1e3;
        let latency = LatencyRecord {
            tick: truth.header.tick,
            control_to_plant_us: us(tick.plant_input_latency_ns),
            measurement_to_estimator_us: us(estimate.header.input_latency_ns),
            estimate_to_dfl_us: us(act.header.input_latency_ns),
        };
        self.write("/pipeline/latency", t, &latency)
    }

    /// A plan as published: its predicted positions, each headed along its velocity.
    pub(super) fn plan(&mut self, plan: &Plan) -> std::io::Result<()> {
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
    pub(super) fn route(&mut self, route: &Route) -> std::io::Result<()> {
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
    pub(super) fn verdict(&mut self, v: &DeadlineVerdict) -> std::io::Result<()> {
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

    /// An event: as a log message (warnings for what went wrong, information otherwise)
    /// on `/events`, and its line of `events.jsonl` (`line`) on `/run/events`.
    pub(super) fn event(&mut self, event: &crate::EventLine, line: &Value) -> std::io::Result<()> {
        const INFO: u8 = 2;
        const WARNING: u8 = 3;
        let level = if event.event.is_warning() {
            WARNING
        } else {
            INFO
        };
        let t = event.t;
        self.write_serde(
            "/events",
            t,
            &json!({
                "timestamp": timestamp(t),
                "level": level,
                "message": line.to_string(),
                "name": event.event.kind(),
                "file": "events.jsonl",
                "line": 0,
            }),
        )?;
        self.write_serde("/run/events", t, line)
    }

    pub(super) fn finish(mut self) -> std::io::Result<()> {
        self.placed_scans(true)?;
        self.out.finish()
    }
}
