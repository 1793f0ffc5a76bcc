//! The path figure of a fleet's run (docs/fleet.md): every robot's path in its colour,
//! its footprint where it started and where its record ended, its goal, and the
//! obstacles at rest.

use super::{Figure, Marker, Ring, Series, Trajectory};
use protocol::Scenario;
use std::path::Path;

/// Writes `path.svg` and `path.png` of the fleet run in `dir` (each robot's record in
/// `dir/robot<id>`).
pub fn fleet_plots(dir: &Path, scenario: &Scenario) -> anyhow::Result<()> {
    let mut series = Vec::new();
    let mut rings = Vec::new();
    let mut markers = Vec::new();
    for id in 0..scenario.robot_count() {
        let robot = scenario.member(id);
        let t = Trajectory::read(&dir.join(format!("robot{id}")))?;
        let path = t.path();
        let footprint = |at: (f64, f64), dashed| Ring {
            at,
            radius: robot.robot.radius_m.max(0.05),
            color: id,
            dashed,
            ..Ring::default()
        };
        if let (Some(first), Some(last)) = (path.first(), path.last()) {
            rings.extend([footprint(*first, true), footprint(*last, false)]);
        }
        series.push(Series {
            label: format!("robot {id}"),
            points: path,
            color: id,
            ..Series::default()
        });
        let [gx, gy] = robot.robot.goal.position;
        markers.push(Marker {
            label: format!("goal {id}"),
            at: (gx, gy),
            color: id,
        });
    }
    Figure {
        stem: "path".into(),
        title: format!(
            "{}: paths of {} robots",
            scenario.name,
            scenario.robot_count()
        ),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series,
        discs: (scenario.obstacles.iter())
            .map(|o| (o.x, o.y, o.radius))
            .collect(),
        rings,
        markers,
        equal_axes: true,
        legend_auto: true,
        ..Figure::default()
    }
    .write(dir)?;
    Ok(())
}
