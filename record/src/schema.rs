//! The record's CSV files: their columns, defined once, and a reader by column name for
//! `figures`, `sweep`, the tests and any tool.

use anyhow::{Context, anyhow};
use std::path::{Path, PathBuf};

/// Columns of `trajectory.csv`, one row per inner tick: time (s); the true pose and
/// zeta (m, rad, m/s); the estimate of the same; the virtual input `v` (m/s^2); the
/// command `u1` (m/s), `u2` (rad/s); the wheel speeds (rad/s); the command mode; the
/// sample of the plan flown; the clearance from the nearest obstacle (m, from the robot's
/// edge).
pub const TRAJECTORY_COLUMNS: [&str; 18] = [
    "t",
    "x",
    "y",
    "theta",
    "zeta",
    "x_hat",
    "y_hat",
    "theta_hat",
    "zeta_hat",
    "v1",
    "v2",
    "u1",
    "u2",
    "omega_r",
    "omega_l",
    "mode",
    "plan_sample",
    "clearance",
];

/// Columns of `plans.csv`, one row per MPC sample: the sample, its time (s), the solver's
/// status, the solve time and the injected delay (us), interior-point iterations, solves,
/// arrival (ms after the sample), whether the deadline was met, the DFL's fallback, the
/// first virtual input (m/s^2), the horizon and the MPC's epoch.
pub const PLANS_COLUMNS: [&str; 14] = [
    "sample",
    "t",
    "status",
    "solve_us",
    "injected_delay_us",
    "iterations",
    "solves",
    "arrival_ms",
    "deadline_met",
    "fallback",
    "v1",
    "v2",
    "horizon",
    "mpc_epoch",
];

/// Columns of `route.csv`, one row per waypoint of every route the planner planned (runs
/// with `planner.kind = "route"`): the plan's number (1 = the first; a restarted or
/// swapped planner counts on), the sample it was planned from, why it was planned, why it
/// replaced the route before (`replanned`: the first, or a stall or stray replan, always
/// taken; `same_way`, `shorter`, `blocked`: a periodic replan, `protocol::RouteSwitch`),
/// and the waypoint (m).
pub const ROUTE_COLUMNS: [&str; 6] = ["plan", "sample", "reason", "switch", "x", "y"];

/// Columns of `tracks.csv`: the tracker's estimate of each tracked obstacle after each
/// measurement (`tick` of it), and its true centre then, m, m/s; `sigma_p_m` and
/// `sigma_v_m_s` are the standard deviations of the position and the velocity along the
/// worse axis.
pub const TRACK_COLUMNS: [&str; 11] = [
    "t",
    "tick",
    "obstacle",
    "x",
    "y",
    "vx",
    "vy",
    "sigma_p_m",
    "sigma_v_m_s",
    "x_true",
    "y_true",
];

/// Columns of `predictions.csv`: the positions (m) the MPC predicted, `i` = 0..=N, in the
/// first solved plan of every whole second of the run (the path figure draws them).
pub const PREDICTION_COLUMNS: [&str; 4] = ["sample", "i", "x", "y"];

/// The header line of a CSV file with `columns`.
pub fn header(columns: &[&str]) -> String {
    columns.join(",")
}

/// A CSV file of the record, its cells by column name.
#[derive(Debug, Clone)]
pub struct Table {
    path: PathBuf,
    columns: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// Reads `path` (a header line, then comma-separated rows).
    pub fn read(path: &Path) -> anyhow::Result<Table> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let mut lines = text.lines();
        let columns = lines
            .next()
            .ok_or_else(|| anyhow!("{}: no header line", path.display()))?
            .split(',')
            .map(String::from)
            .collect();
        let rows = lines
            .map(|l| l.split(',').map(String::from).collect())
            .collect();
        Ok(Table {
            path: path.to_path_buf(),
            columns,
            rows,
        })
    }

    /// Rows after the header.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The cells of column `name`, in row order.
    pub fn column(&self, name: &str) -> anyhow::Result<Vec<&str>> {
        let index = self
            .columns
            .iter()
            .position(|c| c == name)
            .ok_or_else(|| anyhow!("{}: no column {name:?}", self.path.display()))?;
        self.rows
            .iter()
            .enumerate()
            .map(|(n, row)| {
                row.get(index)
                    .map(String::as_str)
                    .ok_or_else(|| anyhow!("{}: line {}: no {name}", self.path.display(), n + 2))
            })
            .collect()
    }

    /// The numbers of column `name`, in row order.
    pub fn numbers(&self, name: &str) -> anyhow::Result<Vec<f64>> {
        self.column(name)?
            .into_iter()
            .enumerate()
            .map(|(n, v)| {
                v.parse().map_err(|_| {
                    anyhow!(
                        "{}: line {}: {name} = {v:?} is not a number",
                        self.path.display(),
                        n + 2
                    )
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_column_is_read_by_name_and_a_missing_one_is_named() {
        let dir = std::env::temp_dir().join(format!("scmpc-schema-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.csv");
        std::fs::write(&path, "t,x,mode\n0,1.5,plan\n0.1,2.5,brake\n").unwrap();
        let table = Table::read(&path).unwrap();
        assert_eq!(table.len(), 2);
        assert_eq!(table.numbers("x").unwrap(), [1.5, 2.5]);
        assert_eq!(table.column("mode").unwrap(), ["plan", "brake"]);
        let err = table.numbers("y").unwrap_err().to_string();
        assert!(err.contains("no column \"y\""), "{err}");
        let err = table.numbers("mode").unwrap_err().to_string();
        assert!(err.contains("line 2: mode = \"plan\""), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
