//! Bad scenarios and overrides are refused before anything runs: exit code 2, and a
//! message naming the file and the key.

mod common;

use common::{run, stderr};

/// Writes `toml` to a scenario file, runs it, and checks the refusal.
fn refused_file(toml: &str, key: &str) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, toml).unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        file.to_str().unwrap(),
        "--in-process",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let msg = stderr(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{toml:?} was not refused: {msg}"
    );
    assert!(
        msg.contains("bad.toml"),
        "message does not name the file: {msg}"
    );
    assert!(msg.contains(key), "message does not name `{key}`: {msg}");
    assert!(
        !out_dir.exists(),
        "a refused scenario still created its run directory"
    );
}

fn refused_set(set: &str, key: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        set,
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let msg = stderr(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "--set {set} was not refused: {msg}"
    );
    assert!(msg.contains(key), "message does not name `{key}`: {msg}");
    assert!(!out_dir.exists());
}

#[test]
fn unparseable_file_is_refused() {
    refused_file("[mpc\nhorizon = 8", "bad.toml");
}

#[test]
fn unknown_key_is_refused() {
    refused_file("[mpc]\ngama = 0.3\n", "gama");
}

#[test]
fn badly_typed_value_is_refused() {
    refused_file("[mpc]\nhorizon = \"eight\"\n", "horizon");
}

#[test]
fn non_positive_sample_period_is_refused() {
    refused_file("[timing]\nts_s = 0.0\n", "timing.ts_s");
    refused_file("[timing]\nts_s = -0.05\n", "timing.ts_s");
}

#[test]
fn zero_horizon_is_refused() {
    refused_file("[mpc]\nhorizon = 0\n", "mpc.horizon");
}

#[test]
fn gamma_outside_zero_one_is_refused() {
    refused_file("[mpc]\ngamma = 0.0\n", "mpc.gamma");
    refused_file("[mpc]\ngamma = 1.5\n", "mpc.gamma");
}

#[test]
fn negative_radius_is_refused() {
    refused_file(
        "[[obstacles]]\nx = 1.0\ny = 1.0\nradius = -0.5\n",
        "obstacles.0.radius",
    );
}

#[test]
fn negative_variance_is_refused() {
    refused_file("[plant]\nnoise_variance = -0.05\n", "plant.noise_variance");
}

#[test]
fn non_finite_number_is_refused() {
    refused_file("[mpc]\nv_max = nan\n", "mpc.v_max");
    refused_file("[robot]\nstart = [inf, 7.0, 0.0]\n", "robot.start.0");
}

#[test]
fn start_inside_an_obstacle_is_refused() {
    refused_file("[robot]\nstart = [3.0, 3.0, 0.0]\n", "robot.start");
}

#[test]
fn constraint_horizon_and_inner_steps_out_of_range_are_refused() {
    refused_file(
        "[mpc]\nconstraint_horizon = 100000\n",
        "mpc.constraint_horizon",
    );
    refused_file("[timing]\ninner_steps = 0\n", "timing.inner_steps");
}

#[test]
fn set_with_unknown_key_is_refused() {
    refused_set("mpc.gama=0.3", "mpc.gama");
}

#[test]
fn set_with_badly_typed_value_is_refused() {
    refused_set("mpc.horizon=abc", "mpc.horizon");
    refused_set("mpc.constraint=circle", "mpc.constraint");
}

#[test]
fn set_with_impossible_value_is_refused() {
    refused_set("mpc.gamma=2", "mpc.gamma");
}

#[test]
fn missing_scenario_file_is_refused() {
    let out = run(&["run", "/nonexistent/scenario.toml", "--in-process"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("/nonexistent/scenario.toml"));
}

#[test]
fn a_start_within_the_robots_radius_of_an_obstacle_is_refused() {
    // 0.2 m from the paper's obstacle's edge, with a robot 0.3 m in radius.
    refused_file(
        "[robot]\nstart = [3.0, 5.2, 0.0]\nradius_m = 0.3\n",
        "robot.start",
    );
    refused_set("robot.radius_m=-0.1", "robot.radius_m");
}

#[test]
fn a_start_whose_braking_path_enters_an_obstacle_is_refused() {
    // 1 m from the obstacle's edge, heading at it at 3 m/s: braking at 3 m/s^2 takes 1.5 m.
    refused_file(
        "[robot]\nstart = [3.0, 6.0, -1.5707963267948966]\nzeta0 = 3.0\n",
        "robot.zeta0",
    );
}

#[test]
fn a_goal_inside_an_obstacle_is_refused() {
    refused_set("robot.goal=[3.0, 3.0]", "robot.goal");
}

#[test]
fn a_brake_the_input_box_cannot_deliver_is_refused_and_auto_follows_the_box() {
    refused_set("dfl.brake_decel=4", "dfl.brake_decel");
    refused_set("dfl.brake_decel=fast", "dfl.brake_decel");
    refused_file(
        "[mpc]\nv_max = 1.0\n[dfl]\nbrake_decel = 2.0\n",
        "dfl.brake_decel",
    );
    // The default brake is the box's: a smaller box alone stays valid.
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        "mpc.v_max=1",
        "--set",
        "duration_s=0.5",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_ne!(out.status.code(), Some(2), "{}", stderr(&out));
    let written = std::fs::read_to_string(dir.path().join("scenario.toml")).unwrap();
    assert!(written.contains("brake_decel = \"auto\""), "{written}");
}

#[test]
fn unknown_safety_settings_are_refused() {
    refused_set("mpc.terminal_safety=sometimes", "mpc.terminal_safety");
    refused_set("dfl.gatekeeper=maybe", "dfl.gatekeeper");
}

#[test]
fn a_start_outside_the_position_box_is_refused() {
    refused_file(
        "[robot]\nstart = [-5.0, 7.0, 0.0]\n\n[mpc]\nposition_min = [0.0, 0.0]\n",
        "robot.start",
    );
}

#[test]
fn a_goal_outside_the_position_box_is_refused() {
    refused_set("robot.goal=[0.0, 12.0]", "robot.goal");
}

#[test]
fn horizon_and_inner_steps_above_their_maxima_are_refused() {
    refused_set(
        &format!("mpc.horizon={}", protocol::MAX_HORIZON + 1),
        "mpc.horizon",
    );
    refused_set(
        &format!("timing.inner_steps={}", protocol::MAX_INNER_STEPS + 1),
        "timing.inner_steps",
    );
}

#[test]
fn a_duration_of_zero_or_less_is_refused() {
    refused_set("duration_s=0", "duration_s");
    refused_set("duration_s=-1", "duration_s");
}

#[test]
fn bad_planner_settings_are_refused() {
    refused_set("planner.kind=astar", "planner.kind");
    refused_set("planner.period_s=-1", "planner.period_s");
    refused_set("planner.clearance_m=-0.1", "planner.clearance_m");
    refused_set("planner.speed_m_s=0", "planner.speed_m_s");
    refused_set("planner.stray_m=0", "planner.stray_m");
    refused_file(
        "[planner]\nkind = \"route\"\n[mpc]\nformulation = \"nonlinear\"\nterminal_safety = \"none\"\n",
        "planner.kind",
    );
}
