//! Issue 27: every goal the validator accepts is reached, or the run says why not.

use crate::common;
use common::*;

/// Issue 27's reduced world: 14.8 m from the goal, `v_max = 1`, `Ts = 0.02 s`, `N = 8`,
/// moving at 0.5 m/s facing away; every solve was infeasible from sample 0.
const FAR: &str = r#"
name = "far"
duration_s = 40.0
[timing]
ts_s = 0.02
[robot]
start = [-3.611, -7.369, 3.3138]
zeta0 = 0.5
goal = [-4.0291, 7.4458]
[mpc]
gamma = 0.3
v_max = 1.0
[[obstacles]]
x = -2.6492
y = 2.2158
radius = 0.9735
[[obstacles]]
x = -4.4048
y = 2.5833
radius = 1.4645
"#;

#[test]
fn the_far_world_with_a_gentle_input_box_is_reached_with_and_without_the_planner() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("far.toml");
    std::fs::write(&file, FAR).unwrap();
    for planner in ["none", "route"] {
        let out_dir = dir.path().join(planner);
        let kind = format!("planner.kind={planner}");
        let out = run(&[
            "run",
            "--in-process",
            file.to_str().unwrap(),
            "--set",
            &kind,
            "--out",
            out_dir.to_str().unwrap(),
        ]);
        assert!(out.status.success(), "{}", stderr(&out));
        let s = summary(&out_dir);
        assert_eq!(s["outcome"], "reached", "{planner}: {s}");
        assert!(
            s["min_clearance_m"].as_f64().unwrap() > 0.0,
            "{planner}: {s}"
        );
        assert_eq!(s["stall_reason"], serde_json::Value::Null);
    }
}

#[test]
fn a_robot_that_cannot_get_past_an_obstacle_says_it_is_pinned_there() {
    let _machine = common::machine_shared();
    // The paper's robot straight behind a wide wall of one disc, without a planner: the
    // CBF holds it at the disc, which lies towards the goal.
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        "robot.start=[6.0, 0.0, 3.14159]",
        "--set",
        "obstacles=[{x = 3.0, y = 0.0, radius = 2.0}]",
        "--set",
        "duration_s=20",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    // A run that does not reach the goal exits 1 (docs/running.md).
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let s = summary(dir.path());
    assert!(
        s["outcome"] == "stalled" || s["outcome"] == "timeout",
        "{s}"
    );
    assert_eq!(s["stall_reason"], "pinned_at_obstacle", "{s}");
    let table = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(table.contains("pinned_at_obstacle"), "{table}");
}
