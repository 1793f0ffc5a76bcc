//! The paper's closed loop, end to end through the `scmpc` executable.

use crate::common;

use common::{run, run_into_tempdir, summary};

#[test]
fn paper_scenario_reaches_the_goal_without_collision() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out = run(&["run", "--in-process", "--out", dir.path().to_str().unwrap()]);
    assert!(out.status.success(), "{}", common::stderr(&out));
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
    let t = s["time_to_goal_s"].as_f64().unwrap();
    assert!((15.0..30.0).contains(&t), "time to goal {t}");
    assert_eq!(s["deadline_misses"], 0);
    assert_eq!(s["steps"], 600);
    for key in ["p50", "p99", "max"] {
        assert!(s["solve_us"][key].as_f64().unwrap() > 0.0);
    }
    // One trajectory row per inner tick, with the columns the README promises.
    let trajectory = std::fs::read_to_string(dir.path().join("trajectory.csv")).unwrap();
    let header = trajectory.lines().next().unwrap();
    for column in [
        "t", "x", "y", "theta", "zeta", "x_hat", "v1", "v2", "u1", "u2", "mode",
    ] {
        assert!(
            header.split(',').any(|c| c == column),
            "no column {column} in {header}"
        );
    }
    assert_eq!(trajectory.lines().count(), 1 + 6000);
    let plans = std::fs::read_to_string(dir.path().join("plans.csv")).unwrap();
    assert_eq!(plans.lines().count(), 1 + 600);
}

#[test]
fn noisy_paper_scenario_with_the_ekf_is_collision_free() {
    let _machine = common::machine_shared();
    for seed in ["1", "2", "3"] {
        let set_seed = format!("seed={seed}");
        let (dir, out) =
            run_into_tempdir(&["run", "paper-noisy", "--in-process", "--set", &set_seed]);
        let s = summary(dir.path());
        assert_ne!(
            s["outcome"],
            "collided",
            "seed {seed}: {}",
            common::stderr(&out)
        );
        let clearance = s["min_clearance_m"].as_f64().unwrap();
        assert!(clearance > 0.0, "seed {seed}: min clearance {clearance}");
    }
}

#[test]
fn same_seed_gives_the_same_trajectory() {
    let _machine = common::machine_shared();
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    for dir in [&a, &b] {
        run(&[
            "run",
            "paper-noisy",
            "--in-process",
            "--set",
            "duration_s=5",
            "--out",
            dir.path().to_str().unwrap(),
        ]);
    }
    let read =
        |d: &tempfile::TempDir| std::fs::read_to_string(d.path().join("trajectory.csv")).unwrap();
    assert_eq!(read(&a), read(&b));
}

#[test]
fn scenario_command_prints_a_scenario_that_runs_as_is() {
    let _machine = common::machine_shared();
    let out = run(&["scenario", "paper"]);
    assert!(out.status.success());
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("mine.toml");
    std::fs::write(&file, &out.stdout).unwrap();
    let run_dir = dir.path().join("run");
    let out = run(&[
        "run",
        file.to_str().unwrap(),
        "--in-process",
        "--set",
        "duration_s=1",
        "--out",
        run_dir.to_str().unwrap(),
    ]);
    assert!(
        run_dir.join("summary.json").exists(),
        "{}",
        common::stderr(&out)
    );
    assert_eq!(summary(&run_dir)["scenario"], "paper");
}

#[test]
fn a_scenario_file_without_a_name_is_called_after_the_file() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("my_robot.toml");
    std::fs::write(&file, "duration_s = 0.5\n").unwrap();
    let run_dir = dir.path().join("run");
    let out = run(&[
        "run",
        file.to_str().unwrap(),
        "--in-process",
        "--no-mcap",
        "--out",
        run_dir.to_str().unwrap(),
    ]);
    assert_ne!(out.status.code(), Some(2), "{}", common::stderr(&out));
    assert_eq!(summary(&run_dir)["scenario"], "my_robot");
    let recorded = std::fs::read_to_string(run_dir.join("scenario.toml")).unwrap();
    assert!(recorded.contains("name = \"my_robot\""), "{recorded}");
}
