//! `summary.json` and the table printed at the end of a run, and the statistics they
//! are made of.

use crate::judge::{Outcome, StallReason};
use serde::Serialize;
use std::collections::BTreeMap;

/// p50 / p99 / max of a sample set (nearest-rank); zeros when empty.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Percentiles {
    pub p50: f64,
    pub p99: f64,
    pub max: f64,
}

impl Percentiles {
    pub fn of(values: &[f64]) -> Percentiles {
        if values.is_empty() {
            return Percentiles::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Percentiles {
            p50: rank(0.50),
            p99: rank(0.99),
            max: v[v.len() - 1],
        }
    }
}

/// How many inner ticks were commanded in each mode.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct ModeCounts {
    pub nominal: u64,
    pub shifted: u64,
    pub brake: u64,
    pub zeta_guard: u64,
    pub safety_brake: u64,
    pub hold: u64,
    pub evasion: u64,
    /// Not the DFL's: ticks the simulated base braked on its own watchdog.
    pub watchdog: u64,
}

impl ModeCounts {
    /// One more tick commanded in `mode`.
    pub fn count(&mut self, mode: protocol::CommandMode) {
        use protocol::CommandMode::*;
        *match mode {
            Nominal => &mut self.nominal,
            Shifted => &mut self.shifted,
            Brake => &mut self.brake,
            ZetaGuard => &mut self.zeta_guard,
            SafetyBrake => &mut self.safety_brake,
            Hold => &mut self.hold,
            Evasion => &mut self.evasion,
            Watchdog => &mut self.watchdog,
        } += 1;
    }
}

/// `summary.json`.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub scenario: String,
    pub seed: u64,
    /// `in-process`, `lockstep` or `realtime`.
    pub mode: String,
    pub outcome: Outcome,
    /// Why a run that stalled or timed out did not arrive (`null` otherwise).
    pub stall_reason: Option<StallReason>,
    /// The signal that stopped an `interrupted` run (`SIGINT`, `SIGTERM`, `SIGHUP`;
    /// `null` otherwise, or when the run was stopped by its caller).
    pub interrupted_by: Option<&'static str>,
    /// Smallest distance from the robot's centre to an obstacle surface, m.
    pub min_clearance_m: f64,
    /// Smallest distance to an obstacle that moves, m (`null` without one).
    pub min_moving_clearance_m: Option<f64>,
    /// Smallest distance to an obstacle that never moves, m (`null` without one).
    pub min_static_clearance_m: Option<f64>,
    /// Contacts the robot made while it moved (a run ends `collided` at the first).
    pub contacts_moving: u64,
    /// Contacts a moving obstacle made with the robot at rest (the run goes on).
    pub contacts_at_rest: u64,
    /// First time after which the robot stayed within the goal tolerance, s.
    pub time_to_goal_s: Option<f64>,
    /// First time the robot was more than 5 cm off the straight start-goal line, s.
    pub deviation_time_s: Option<f64>,
    pub final_distance_to_goal_m: f64,
    /// How far the final heading is from the goal's, rad (`null`: a goal without one).
    pub final_heading_error_rad: Option<f64>,
    /// The final approach (`null`: never within 0.2 m of the goal).
    pub arrival: Option<ArrivalReport>,
    /// Samples whose plan was not in the DFL's hands by `t_k + Ts`, or failed.
    pub deadline_misses: u64,
    /// Longest run of consecutive deadline misses.
    pub longest_miss_streak: u64,
    /// Faults injected into the run (empty for a clean run).
    pub faults: Vec<String>,
    /// Plans whose solver status was not `solved`.
    pub solver_failures: u64,
    /// Times the DFL's safety check acted: a plan refused, or the committed trajectory
    /// given up for the brake (events `safety_intervention`).
    pub safety_interventions: u64,
    /// MPC samples run.
    pub steps: u64,
    /// Inner ticks run.
    pub ticks: u64,
    pub simulated_s: f64,
    pub wall_s: f64,
    /// Wall time of each MPC step (update, every solve), µs.
    pub solve_us: Percentiles,
    /// Interior-point iterations per MPC step.
    pub iterations: Percentiles,
    /// How far the robot was, one sample after each solved plan, from where that plan put
    /// it, mm: how well the model the MPC and the DFL fly holds for the robot (a base's lag
    /// and delay, `robot.actuator_lag_s`, `robot.command_delay_s`, docs/robot.md).
    pub plan_following_mm: Percentiles,
    pub commands: ModeCounts,
    /// Plans of the route planner after the first (`planner.kind = "route"`).
    pub replans: u64,
    /// Length of the first route, m (`None`: no planner, or no route).
    pub route_length_m: Option<f64>,
    /// The ROS 2 robot of `plant.kind = "ros2"` (docs/ros2.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub robot: Option<RobotReport>,
    /// Tracks born, lost and false, and obstacles missed: runs of the simulated plant that
    /// see with a lidar (`null` otherwise).
    pub perception: Option<crate::perception::PerceptionReport>,
    /// Only for runs over iceoryx2 (not `--in-process`).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub processes: Option<ProcessReport>,
}

/// The final approach ([`crate::judge::Arrival`]), as `summary.json` and the end table
/// give it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ArrivalReport {
    /// First time within 0.2 m of the goal, s.
    pub within_0_2_m_s: f64,
    /// Largest distance to the goal after that, m.
    pub largest_distance_after_m: f64,
    /// From then to the stay within `rest_within_m` that lasts to the end of the run, s
    /// (`null`: the run ended outside it).
    pub time_to_rest_s: Option<f64>,
    /// The rest radius: 0.05 m, or the goal tolerance if smaller, m.
    pub rest_within_m: f64,
}

impl ArrivalReport {
    /// The report of `arrival` (`None`: the robot never came within 0.2 m of its goal).
    pub fn of(arrival: &crate::judge::Arrival) -> Option<ArrivalReport> {
        Some(ArrivalReport {
            within_0_2_m_s: arrival.arriving_s?,
            largest_distance_after_m: arrival.farthest_after_m,
            time_to_rest_s: arrival.time_to_rest_s(),
            rest_within_m: arrival.rest_within_m,
        })
    }

    /// Its row of the end table.
    fn text(&self) -> String {
        let rest = self.time_to_rest_s.map_or_else(
            || format!("not at rest within {} m at the end", self.rest_within_m),
            |t| format!("at rest within {} m {t:.2} s later", self.rest_within_m),
        );
        format!(
            "within 0.2 m at {:.2} s, then out to {:.3} m; {rest}",
            self.within_0_2_m_s, self.largest_distance_after_m
        )
    }
}

/// Where a ROS 2 robot's run started and went: its first odometry replaces `robot.start`.
#[derive(Debug, Clone, Serialize)]
pub struct RobotReport {
    /// The robot's Zenoh router.
    pub endpoint: String,
    /// The first odometry's pose, `[x_m, y_m, yaw_rad]`.
    pub start: [f64; 3],
    /// `[x_m, y_m]` in the odometry's frame.
    pub goal: [f64; 2],
    /// `robot.goal`, or the goal topic it came from.
    pub goal_from: String,
}

impl RobotReport {
    /// The report of `scenario`'s robot, if it drives one (its start is the first
    /// odometry's by then).
    pub fn of(scenario: &protocol::Scenario) -> Option<RobotReport> {
        let r = &scenario.ros2;
        (scenario.plant.kind == protocol::PlantKind::Ros2).then(|| RobotReport {
            endpoint: r.endpoint.clone(),
            start: scenario.robot.start,
            goal: scenario.robot.goal.position,
            goal_from: if r.wait_for_goal {
                r.goal_topic.clone()
            } else {
                "robot.goal".into()
            },
        })
    }

    fn row(&self) -> String {
        let [x, y, yaw] = self.start;
        let [gx, gy] = self.goal;
        format!(
            "ROS 2 via {}: start ({x:.3}, {y:.3}, {yaw:.3}) from its first odometry \
             (robot.start ignored), goal ({gx:.3}, {gy:.3}) from {}",
            self.endpoint, self.goal_from
        )
    }
}

/// What a multi-process run adds to the summary.
#[derive(Debug, Clone, Default, Serialize)]
pub struct ProcessReport {
    /// PID of every process of the run, by role (and `orchestrator`).
    pub pids: BTreeMap<String, u32>,
    /// The run's iceoryx2 resource prefix.
    pub iceoryx2_prefix: String,
    /// Publish-to-receipt latency of every hop, pooled, µs.
    pub hop_latency_us: Percentiles,
    /// The same per hop (`producer_to_consumer`), µs.
    pub hop_latency_by_hop_us: BTreeMap<String, Percentiles>,
    /// Measurement published to actuation published for the same tick, on ticks that are
    /// not sample boundaries (so without the MPC solve), µs.
    pub loop_latency_us: Percentiles,
    /// A ROS 2 robot's odometry: its age when it reached the pipeline (the wall clock then
    /// less its stamp), µs; `None` with the simulated plant.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub odometry_age_us: Option<Percentiles>,
    /// Ticks the recorder never received whole (real time only; lockstep waits).
    pub record_gaps: u64,
    /// Ticks commanded without an estimate (the DFL braking on its own clock).
    pub ticks_without_estimate: u64,
    /// Peak resident memory of each process at the end of the run (`VmHWM`), KiB.
    pub peak_rss_kib: BTreeMap<String, u64>,
    /// Real time: how each process on this host ran, as the kernel said once it was ready
    /// (`[realtime]`; docs/running.md, "Real-time scheduling"). Empty in lockstep.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub scheduling: BTreeMap<String, Scheduling>,
    /// Processes restarted after a crash.
    pub restarts: u32,
    /// Swap-in replacements that took over (details in events.jsonl).
    pub swaps: u32,
    /// Swaps that started and did not take over, one line each: the role, the epoch, the
    /// command and why (the old process stayed the producer).
    pub failed_swaps: Vec<String>,
    /// Samples refused by the consumers (non-finite, tick backwards, wrong run, wrong
    /// epoch), by reason; never applied.
    pub rejected_samples: BTreeMap<String, u64>,
    /// iceoryx2 files of the run still present after it ended (should be empty).
    pub leftover_files: Vec<String>,
    /// The host each role ran on (roles on other hosts only; docs/hosts.md).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub hosts: BTreeMap<String, String>,
    /// Each link to another host: its round trip, the clock offset and what it carried.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub links: BTreeMap<String, LinkReport>,
    /// What the orchestrator's own bridge carried and refused, over all its links.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub orchestrator_bridge: Option<protocol::endpoint::LinkCounters>,
}

/// How a process was scheduled, as `/proc` tells of its main thread.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Scheduling {
    /// `fifo`, `rr`, `other` (Linux's normal policy), `batch` or `idle`.
    pub policy: String,
    /// Its real-time priority (0 under `other`).
    pub priority: u32,
    /// Whether its memory is locked (`VmLck` above zero).
    pub memory_locked: bool,
    /// The CPUs it may run on (`Cpus_allowed_list`, e.g. `0-1`).
    pub cpus: String,
}

impl Scheduling {
    /// `fifo 50, locked, cpus 0-1`.
    fn short(&self) -> String {
        let mut text = self.policy.clone();
        if self.priority > 0 {
            text += &format!(" {}", self.priority);
        }
        if self.memory_locked {
            text += ", locked";
        }
        text + &format!(", cpus {}", self.cpus)
    }
}

/// One link between the orchestrator's host and another (docs/hosts.md).
#[derive(Debug, Clone, Default, Serialize)]
pub struct LinkReport {
    /// Where the host's agent listened.
    pub endpoint: String,
    /// The shortest round trip of the clock exchange, µs.
    pub round_trip_us: f64,
    /// The host's clock against the orchestrator's, as estimated, ms (positive: behind).
    pub clock_correction_ms: f64,
    /// How far that estimate may be off (half the round trip), µs.
    pub clock_uncertainty_us: f64,
    /// What the host's bridge carried and refused (`null` when the host was lost: its
    /// agent could not say).
    pub host_bridge: Option<protocol::endpoint::LinkCounters>,
    /// Whether the host's agent went away during the run.
    pub lost: bool,
}

/// Latency samples of a multi-process run, collected by the recorder.
#[derive(Debug, Default)]
pub struct Latencies {
    hops: BTreeMap<&'static str, Vec<f64>>,
    loop_us: Vec<f64>,
    odometry_age_us: Vec<f64>,
}

impl Latencies {
    /// One hop's publish-to-receipt latency, ns (0 means not measured).
    pub fn hop(&mut self, hop: &'static str, latency_ns: u64) {
        if latency_ns > 0 {
            self.hops
                .entry(hop)
                .or_default()
                .push(latency_ns as f64 / 1e3);
        }
    }
    pub fn sensor_to_actuator(&mut self, latency_ns: u64) {
        self.loop_us.push(latency_ns as f64 / 1e3);
    }
    /// How old a ROS 2 robot's odometry was when it arrived, ns.
    pub fn odometry_age(&mut self, age_ns: u64) {
        self.odometry_age_us.push(age_ns as f64 / 1e3);
    }
    /// Fills the latency fields of `report`.
    pub fn report(&self, report: &mut ProcessReport) {
        let pooled: Vec<f64> = self.hops.values().flatten().copied().collect();
        report.hop_latency_us = Percentiles::of(&pooled);
        report.hop_latency_by_hop_us = self
            .hops
            .iter()
            .map(|(k, v)| (k.to_string(), Percentiles::of(v)))
            .collect();
        report.loop_latency_us = Percentiles::of(&self.loop_us);
        report.odometry_age_us =
            (!self.odometry_age_us.is_empty()).then(|| Percentiles::of(&self.odometry_age_us));
    }
}

impl Summary {
    /// The short table printed at the end of a run (one line per row of the table, in the
    /// order printed: long, but a list).
    /// The outcome, with why the robot stalled or which signal interrupted the run.
    fn outcome_text(&self) -> String {
        match (self.stall_reason, self.interrupted_by) {
            (Some(reason), _) => format!("{} ({})", self.outcome.as_str(), reason.as_str()),
            (None, Some(signal)) => format!("{} ({signal})", self.outcome.as_str()),
            (None, None) => self.outcome.as_str().to_string(),
        }
    }

    pub fn table(&self) -> String {
        let opt = |v: Option<f64>| v.map_or("never".to_string(), |t| format!("{t:.2} s"));
        let rows = [
            (
                "scenario",
                format!("{} (seed {}, {})", self.scenario, self.seed, self.mode),
            ),
            ("outcome", self.outcome_text()),
            ("min clearance", format!("{:.3} m", self.min_clearance_m)),
            ("time to goal", opt(self.time_to_goal_s)),
            (
                "final distance",
                format!("{:.3} m", self.final_distance_to_goal_m),
            ),
            (
                "final heading",
                self.final_heading_error_rad
                    .map_or("no goal heading".into(), |e| {
                        format!("{e:.3} rad from the goal's")
                    }),
            ),
            (
                "arrival",
                self.arrival
                    .map_or("never within 0.2 m".to_string(), |a| a.text()),
            ),
            (
                "samples / ticks",
                format!("{} / {}", self.steps, self.ticks),
            ),
            (
                "deadline misses",
                format!(
                    "{} (longest run {}; {} solver failures)",
                    self.deadline_misses, self.longest_miss_streak, self.solver_failures
                ),
            ),
            (
                "commands",
                format!(
                    "nominal {}, shifted {}, brake {}, zeta_guard {}, safety_brake {}, hold {}, evasion {}, watchdog {}",
                    self.commands.nominal,
                    self.commands.shifted,
                    self.commands.brake,
                    self.commands.zeta_guard,
                    self.commands.safety_brake,
                    self.commands.hold,
                    self.commands.evasion,
                    self.commands.watchdog
                ),
            ),
            (
                "safety checks",
                format!("{} interventions", self.safety_interventions),
            ),
        ];
        let table: String = (rows.iter().chain(&self.timing_rows()))
            .map(|(k, v)| format!("  {k:<16} {v}\n"))
            .collect();
        table + &self.rows_of_what_ran()
    }

    /// The end table's rows of how the robot followed its plans and how long it took.
    fn timing_rows(&self) -> [(&'static str, String); 3] {
        [
            (
                "plan following",
                format!(
                    "p50 {:.3} mm, p99 {:.3} mm, max {:.3} mm off each plan one sample on",
                    self.plan_following_mm.p50,
                    self.plan_following_mm.p99,
                    self.plan_following_mm.max
                ),
            ),
            (
                "solve time",
                format!(
                    "p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
                    self.solve_us.p50, self.solve_us.p99, self.solve_us.max
                ),
            ),
            (
                "wall time",
                format!(
                    "{:.2} s for {:.1} s simulated",
                    self.wall_s, self.simulated_s
                ),
            ),
        ]
    }

    /// The end table's rows of what only some runs have: moving obstacles, a route, a
    /// robot, faults, processes.
    fn rows_of_what_ran(&self) -> String {
        let mut table = String::new();
        if let Some(clearance) = self.min_moving_clearance_m {
            table += &format!(
                "  {:<16} least clearance {clearance:.3} m; contacts: {} while moving, {} at rest\n",
                "moving obstacles", self.contacts_moving, self.contacts_at_rest
            );
        }
        if let Some(length) = self.route_length_m {
            table += &format!(
                "  {:<16} {length:.2} m, {} replans\n",
                "route", self.replans
            );
        }
        if let Some(robot) = &self.robot {
            table += &format!("  {:<16} {}\n", "robot", robot.row());
        }
        if let Some(p) = &self.perception {
            table += &format!(
                "  {:<16} tracks: {} born, {} lost, {} false; {} obstacles missed\n",
                "perception", p.tracks_born, p.tracks_lost, p.false_tracks, p.missed_obstacles
            );
        }
        for fault in &self.faults {
            table += &format!("  {:<16} {fault}\n", "injected fault");
        }
        if let Some(p) = &self.processes {
            table += &p.table();
        }
        table
    }
}

impl ProcessReport {
    /// The end table's rows of a multi-process run: latencies, processes, hosts, what was
    /// not recorded or left behind.
    fn table(&self) -> String {
        let mut table = String::new();
        let line = |name: &str, q: &Percentiles| {
            format!(
                "  {name:<16} p50 {:.1} µs, p99 {:.1} µs, max {:.1} µs\n",
                q.p50, q.p99, q.max
            )
        };
        table += &line("hop latency", &self.hop_latency_us);
        table += &line("sensor→actuator", &self.loop_latency_us);
        if let Some(age) = &self.odometry_age_us {
            table += &line("odometry age", age);
        }
        let pids: Vec<String> = self
            .pids
            .iter()
            .map(|(r, pid)| format!("{r} {pid}"))
            .collect();
        table += &format!("  {:<16} {}\n", "processes", pids.join(", "));
        if !self.scheduling.is_empty() {
            let each: Vec<String> = self
                .scheduling
                .iter()
                .map(|(r, s)| format!("{r} {}", s.short()))
                .collect();
            table += &format!("  {:<16} {}\n", "scheduling", each.join("; "));
        }
        for (role, host) in &self.hosts {
            let link = self.links.get(host);
            table += &format!(
                "  {:<16} {role} on `{host}`{}\n",
                "host",
                link.map_or(String::new(), |l| format!(
                    " ({}, round trip {:.0} µs, clock {:+.3} ms ± {:.0} µs){}",
                    l.endpoint,
                    l.round_trip_us,
                    l.clock_correction_ms,
                    l.clock_uncertainty_us,
                    if l.lost { ", lost during the run" } else { "" }
                ))
            );
        }
        for failed in &self.failed_swaps {
            table += &format!("  {:<16} {failed}\n", "failed swap");
        }
        if self.record_gaps > 0 {
            table += &format!(
                "  {:<16} {} ticks not recorded whole\n",
                "record gaps", self.record_gaps
            );
        }
        if !self.leftover_files.is_empty() {
            table += &format!(
                "  {:<16} {} iceoryx2 files left behind\n",
                "leftovers",
                self.leftover_files.len()
            );
        }
        table
    }
}
