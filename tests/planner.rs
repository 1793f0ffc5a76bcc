//! The route planner (docs/planner.md): random obstacle fields reached, the
//! `field` scenario in every clock, no route, a planner killed or swapped mid-run.

use crate::common;

use common::{csv, events, has_event, num, run, run_into_tempdir, stderr, summary};
use std::path::Path;

/// Writes the scenario `text` into `dir` and runs it (lockstep) into `dir/run`; returns
/// that directory and the output.
fn run_file(dir: &Path, text: &str) -> (std::path::PathBuf, std::process::Output) {
    let path = dir.join("scenario.toml");
    std::fs::write(&path, text).unwrap();
    let out_dir = dir.join("run");
    let out = run(&[
        "run",
        path.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    (out_dir, out)
}

#[test]
fn with_the_planner_random_worlds_reach_the_goal_when_a_route_exists_and_never_collide() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "fuzz",
        "--count",
        "200",
        "--seed",
        "17",
        "--set",
        "planner.kind=route",
        // The planner's worlds at rest (people on the way: tests/fuzz.rs, tests/moving.rs).
        "--people",
        "0",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    let rows = csv(&dir.path().join("fuzz.csv"));
    assert_eq!(rows.len(), 200, "{}", stderr(&out));
    let count = |outcome: &str| rows.iter().filter(|r| r["outcome"] == outcome).count();
    assert_eq!(count("collided"), 0);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    // A reach rate over the worlds with a route says nothing if few have one: in the
    // widened worlds a route is closed only where noise grows the obstacles across it
    // (1 in 1000 with the noise forced to 0.01, docs/reach.md).
    assert!(
        count("no_route") <= 2,
        "{} of 200 without a route",
        count("no_route")
    );
    let routable = rows.len() - count("no_route");
    let reached = count("reached");
    assert!(
        reached as f64 >= 0.95 * routable as f64,
        "reached {reached} of {routable} worlds with a route"
    );
    for row in &rows {
        assert!(num(row, "min_clearance_m") > 0.0, "{row:?}");
    }
}

/// The `field` scenario run in `mode` (`--in-process` or a `--mode`) into a fresh
/// directory; its summary must say it reached the goal.
fn field(mode: &[&str]) -> tempfile::TempDir {
    let (dir, out) = run_into_tempdir(&[&["run", "field"], mode].concat());
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached", "{mode:?}");
    assert!(s["route_length_m"].as_f64().unwrap() > 0.0);
    dir
}

#[test]
fn the_field_is_reached_in_lockstep_exactly_as_in_process_and_not_without_the_planner() {
    let _machine = common::machine_shared();
    let lockstep = field(&[]);
    let in_process = field(&["--in-process"]);
    for file in ["trajectory.csv", "route.csv"] {
        let read = |dir: &Path| std::fs::read(dir.join(file)).unwrap();
        assert!(
            read(lockstep.path()) == read(in_process.path()),
            "{file} differs between lockstep and in-process"
        );
    }
    let routes = csv(&lockstep.path().join("route.csv"));
    assert_eq!(routes[0]["reason"], "start");
    assert_eq!(
        (num(&routes[0], "x"), num(&routes[0], "y")),
        (8.0, 7.0),
        "the first route starts at the start"
    );
    // Why each route replaced the one before: a periodic replan only when the old one is
    // blocked or the new one is shorter (the same way round, or another by the margin);
    // the first route and the stall and stray replans always.
    for r in &routes {
        let expected: &[&str] = match r["reason"].as_str() {
            "period" => &["same_way", "shorter", "blocked"],
            _ => &["replanned"],
        };
        assert!(expected.contains(&r["switch"].as_str()), "{r:?}");
    }
    // The paper's controller alone does not get through this field.
    let (none, out) =
        run_into_tempdir(&["run", "field", "--in-process", "--set", "planner.kind=none"]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert_eq!(summary(none.path())["outcome"], "stalled");
}

#[test]
fn a_goal_walled_in_ends_the_run_at_once_with_no_route() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    // Eight discs in a ring around the goal, overlapping.
    let mut file = String::from("name = \"walled\"\n[planner]\nkind = \"route\"\n");
    for k in 0..8 {
        let a = f64::from(k) * std::f64::consts::TAU / 8.0;
        file += &format!(
            "[[obstacles]]\nx = {}\ny = {}\nradius = 0.7\n",
            1.5 * a.cos(),
            1.5 * a.sin()
        );
    }
    let (out_dir, out) = run_file(dir.path(), &file);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let s = summary(&out_dir);
    assert_eq!(s["outcome"], "no_route");
    // At once: within the first sample's route, not after a stall timeout.
    assert!(s["simulated_s"].as_f64().unwrap() < 0.2, "{s}");
    assert!(events(&out_dir).iter().any(|e| e["event"] == "no_route"));
}

#[test]
fn in_real_time_the_field_is_reached_with_no_deadline_miss_through_a_planner_killed_mid_run() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        common::kill_role_during_run(dir.path(), &["field", "--mode", "realtime"], "planner", 5.0);
        let s = summary(dir.path());
        let ev = events(dir.path());
        assert!(has_event(&ev, "restarted", "planner"), "{ev:#?}");
        assert_eq!(s["outcome"], "reached");
        machine.judge(&ev)?;
        // The restarted planner planned again, from where the robot was: its route's first
        // waypoint is the robot's position at the sample it planned from, far from the start.
        let routes = csv(&dir.path().join("route.csv"));
        let restarted = routes
            .iter()
            .find(|r| r["plan"] != "1" && r["reason"] == "start")
            .expect("no route of the restarted planner");
        let from = [num(restarted, "x"), num(restarted, "y")];
        let field = run::scenarios::load(Some("field"), &[]).unwrap();
        let planned_s = num(restarted, "sample") * field.timing.ts_s;
        let trajectory = csv(&dir.path().join("trajectory.csv"));
        let then = trajectory
            .iter()
            .find(|r| num(r, "t") >= planned_s - 1e-9)
            .expect("no tick at the planned sample");
        let robot_then = [num(then, "x_hat"), num(then, "y_hat")];
        let off = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).hypot(a[1] - b[1]);
        assert!(
            off(from, robot_then) < 0.05,
            "planned from {from:?}, the robot at {robot_then:?}"
        );
        let start = [field.robot.start[0], field.robot.start[1]];
        assert!(off(from, start) > 1.0, "planned from {from:?}, the start");
        Ok(())
    })
}

#[test]
fn the_planner_is_swapped_in_lockstep_and_a_run_without_one_refuses_its_swap() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let field = String::from_utf8(run(&["scenario", "field"]).stdout).unwrap();
    let swap = format!("{field}\n[[swap]]\ntime_s = 4.0\nrole = \"planner\"\n");
    let (out_dir, out) = run_file(dir.path(), &swap);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let s = summary(&out_dir);
    assert_eq!(s["swaps"], 1);
    assert_eq!(s["outcome"], "reached");
    assert!(s["rejected_samples"].as_object().unwrap().is_empty(), "{s}");
    assert!(has_event(&events(&out_dir), "swapped", "planner"));

    let refused = tempfile::tempdir().unwrap();
    let no_planner = "name = \"no-planner\"\n[[swap]]\ntime_s = 4.0\nrole = \"planner\"\n";
    let (refused_dir, out) = run_file(refused.path(), no_planner);
    assert_eq!(out.status.code(), Some(2));
    assert!(!refused_dir.exists(), "a refused scenario started a run");
    assert!(stderr(&out).contains("swap.0.role"), "{}", stderr(&out));
}
