//! The record of a fleet (docs/fleet.md): how close its robots came to each other, who
//! touched whom, and the summary of the fleet beside each robot's own.

use crate::Summary;
use crate::judge::Outcome;
use serde::Serialize;

/// A robot moves when its centre went at least this fast over the last tick, m/s: below
/// it, a robot touched was at rest (walked into, not walking).
pub const MOVING_SPEED_M_S: f64 = 1e-3;

/// The judge between a fleet's robots: their true clearance every tick, and each contact
/// (a pair's footprints overlapping, from the tick they start to) counted once, against
/// every robot of the pair that moved then or as at rest.
#[derive(Debug, Clone)]
pub struct FleetJudge {
    radii: Vec<f64>,
    /// Each robot's position at the last tick, m.
    last: Vec<Option<[f64; 2]>>,
    /// Whether each robot moved over this tick (kept to spare a tick's allocation).
    moving: Vec<bool>,
    /// Whether each pair `(i, j)`, `j < i`, touches now (`i (i - 1) / 2 + j`).
    touching: Vec<bool>,
    /// The smallest clearance between two robots' footprints so far, m.
    pub min_clearance_m: f64,
    /// By robot: contacts it moved into, and contacts while it was at rest.
    pub contacts_moving: Vec<u64>,
    pub contacts_at_rest: Vec<u64>,
}

impl FleetJudge {
    /// A judge of robots with footprints of `radii`, m.
    pub fn new(radii: Vec<f64>) -> FleetJudge {
        let n = radii.len();
        FleetJudge {
            radii,
            last: vec![None; n],
            moving: vec![false; n],
            touching: vec![false; n * n.saturating_sub(1) / 2],
            min_clearance_m: f64::INFINITY,
            contacts_moving: vec![0; n],
            contacts_at_rest: vec![0; n],
        }
    }

    /// The robots' true positions at one tick, `dt_s` after the last: the contacts that
    /// start at it, as `(i, j)` pairs.
    pub fn tick(&mut self, positions: &[[f64; 2]], dt_s: f64) -> Vec<(usize, usize)> {
        for ((moving, p), last) in self.moving.iter_mut().zip(positions).zip(&self.last) {
            *moving = last.is_some_and(|q| protocol::distance(*p, q) > MOVING_SPEED_M_S * dt_s);
        }
        let mut started = Vec::new();
        for i in 0..positions.len() {
            for j in 0..i {
                let gap =
                    protocol::distance(positions[i], positions[j]) - self.radii[i] - self.radii[j];
                self.min_clearance_m = self.min_clearance_m.min(gap);
                let pair = i * (i - 1) / 2 + j;
                let touches = gap < 0.0;
                if touches && !self.touching[pair] {
                    started.push((i, j));
                    for k in [i, j] {
                        match self.moving[k] {
                            true => self.contacts_moving[k] += 1,
                            false => self.contacts_at_rest[k] += 1,
                        }
                    }
                }
                self.touching[pair] = touches;
            }
        }
        for (last, p) in self.last.iter_mut().zip(positions) {
            *last = Some(*p);
        }
        started
    }
}

/// One robot of a fleet in the fleet's summary.
#[derive(Debug, Clone, Serialize)]
pub struct FleetMember {
    pub id: usize,
    pub outcome: Outcome,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stall_reason: Option<crate::judge::StallReason>,
    pub time_to_goal_s: Option<f64>,
    /// Its clearance to the obstacles, m (its own `summary.json`).
    pub min_clearance_m: f64,
    /// Contacts with another robot while it moved, and while it was at rest.
    pub robot_contacts_moving: u64,
    pub robot_contacts_at_rest: u64,
    /// Times a moving obstacle (a person) came into it while it was at rest (its own
    /// `summary.json`'s `contacts_at_rest`; one while it moved is its outcome, `collided`).
    pub contacts_at_rest: u64,
    /// Deadlocks it broke by giving way (docs/fleet.md, "Deadlocks").
    pub deadlocks_broken: u64,
    pub deadline_misses: u64,
    /// Its MPC step, µs.
    pub solve_us: crate::Percentiles,
}

/// A fleet's `summary.json`: each robot's line, and the fleet's.
#[derive(Debug, Clone, Serialize)]
pub struct FleetSummary {
    pub scenario: String,
    pub seed: u64,
    pub mode: String,
    pub robots: Vec<FleetMember>,
    pub reached: usize,
    /// The smallest clearance between two robots' footprints, m.
    pub min_robot_clearance_m: f64,
    pub robot_contacts_moving: u64,
    pub robot_contacts_at_rest: u64,
    pub deadlocks_broken: u64,
    /// The last robot's time to its goal, s (`None` unless all reached).
    pub time_to_all_goals_s: Option<f64>,
    pub simulated_s: f64,
    pub wall_s: f64,
}

impl FleetSummary {
    /// The fleet's summary from each robot's, the fleet judge and the deadlocks each broke.
    pub fn of(
        summaries: &[Summary],
        judge: &FleetJudge,
        deadlocks: &[u64],
        simulated_s: f64,
        wall_s: f64,
    ) -> FleetSummary {
        let robots: Vec<FleetMember> = (summaries.iter().enumerate())
            .map(|(id, s)| FleetMember {
                id,
                outcome: s.outcome,
                stall_reason: s.stall_reason,
                time_to_goal_s: s.time_to_goal_s,
                min_clearance_m: s.min_clearance_m,
                robot_contacts_moving: judge.contacts_moving[id],
                robot_contacts_at_rest: judge.contacts_at_rest[id],
                contacts_at_rest: s.contacts_at_rest,
                deadlocks_broken: deadlocks[id],
                deadline_misses: s.deadline_misses,
                solve_us: s.solve_us,
            })
            .collect();
        let reached = (robots.iter())
            .filter(|r| r.outcome == Outcome::Reached)
            .count();
        let time_to_all_goals_s = (reached == robots.len()).then(|| {
            robots
                .iter()
                .filter_map(|r| r.time_to_goal_s)
                .fold(0.0, f64::max)
        });
        FleetSummary {
            scenario: summaries
                .first()
                .map_or(String::new(), |s| s.scenario.clone()),
            seed: summaries.first().map_or(0, |s| s.seed),
            mode: summaries.first().map_or(String::new(), |s| s.mode.clone()),
            reached,
            min_robot_clearance_m: judge.min_clearance_m,
            robot_contacts_moving: judge.contacts_moving.iter().sum::<u64>(),
            robot_contacts_at_rest: judge.contacts_at_rest.iter().sum::<u64>(),
            deadlocks_broken: deadlocks.iter().sum(),
            time_to_all_goals_s,
            robots,
            simulated_s,
            wall_s,
        }
    }

    /// Writes it as `dir/summary.json`, whichever executor ran the fleet.
    pub fn write(&self, dir: &std::path::Path) -> std::io::Result<()> {
        let path = dir.join("summary.json");
        std::fs::write(&path, serde_json::to_string_pretty(self)? + "\n")
            .map_err(|e| std::io::Error::new(e.kind(), format!("writing {}: {e}", path.display())))
    }

    /// Whether every robot reached its goal without touching another.
    pub fn all_reached(&self) -> bool {
        self.reached == self.robots.len() && self.robot_contacts_moving == 0
    }

    /// The end table: a line per robot, then the fleet's.
    pub fn table(&self) -> String {
        let secs = |t: Option<f64>| t.map_or("never".to_string(), |t| format!("{t:.2} s"));
        let mut out = format!(
            "fleet {} (seed {}, {}): {} robots\n",
            self.scenario,
            self.seed,
            self.mode,
            self.robots.len()
        );
        out += "  robot  outcome     to goal    obstacles  contacts (moving/at rest)  deadlocks broken\n";
        for r in &self.robots {
            let clearance = match r.min_clearance_m.is_finite() {
                true => format!("{:.3} m", r.min_clearance_m),
                false => "none".into(),
            };
            out += &format!(
                "  {:>5}  {:<10}  {:>8}  {:>10}  {:>12}/{:<12}  {:>6}\n",
                r.id,
                r.outcome.as_str(),
                secs(r.time_to_goal_s),
                clearance,
                r.robot_contacts_moving,
                r.robot_contacts_at_rest,
                r.deadlocks_broken
            );
        }
        out += &format!(
            "  reached {} of {}; robot-robot clearance {:.3} m; contacts {} moving, {} at rest; \
             deadlocks broken {}; all at their goals {}\n  simulated {:.1} s in {:.1} s wall\n",
            self.reached,
            self.robots.len(),
            self.min_robot_clearance_m,
            self.robot_contacts_moving,
            self.robot_contacts_at_rest,
            self.deadlocks_broken,
            secs(self.time_to_all_goals_s),
            self.simulated_s,
            self.wall_s
        );
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_contact_counts_once_against_the_robot_that_moved_and_the_one_at_rest() {
        let mut judge = FleetJudge::new(vec![0.3, 0.3]);
        let dt = 0.01;
        assert!(judge.tick(&[[0.0, 0.0], [1.0, 0.0]], dt).is_empty());
        // Robot 1 moves into robot 0, which stands, and stays in contact two ticks.
        assert_eq!(judge.tick(&[[0.0, 0.0], [0.5, 0.0]], dt), vec![(1, 0)]);
        assert!(judge.tick(&[[0.0, 0.0], [0.55, 0.0]], dt).is_empty());
        assert_eq!(judge.contacts_moving, vec![0, 1]);
        assert_eq!(judge.contacts_at_rest, vec![1, 0]);
        assert!((judge.min_clearance_m - -0.1).abs() < 1e-12);
    }
}
