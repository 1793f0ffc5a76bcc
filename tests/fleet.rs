//! A fleet (docs/fleet.md): several robots, each its own pipeline, in one world.

mod common;

use common::{events, run, run_into_tempdir, stderr, summary};

/// `swap4`: four robots exchange places through the circle's centre. Every robot reaches
/// its goal, none touches another, and the symmetric encounter is broken by robots giving
/// way, each a `gave_way` event in its record.
#[test]
fn swap4_every_robot_reaches_its_goal_without_contact_after_giving_way() {
    let (dir, out) = run_into_tempdir(&["run", "swap4", "--in-process", "--no-mcap"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let fleet = summary(dir.path());
    assert_eq!(fleet["reached"], 4, "{fleet}");
    assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
    assert_eq!(fleet["robot_contacts_at_rest"], 0, "{fleet}");
    assert!(fleet["min_robot_clearance_m"].as_f64().unwrap() > 0.0);
    let broken = fleet["deadlocks_broken"].as_u64().unwrap();
    assert!(broken > 0, "nobody gave way: {fleet}");
    let mut gave_way = 0;
    for id in 0..4 {
        let robot = dir.path().join(format!("robot{id}"));
        assert_eq!(summary(&robot)["outcome"], "reached");
        gave_way += (events(&robot).iter())
            .filter(|e| e["event"] == "gave_way")
            .count() as u64;
    }
    assert_eq!(gave_way, broken, "an event for every deadlock broken");
}

/// A fleet in process is deterministic: the same scenario gives every robot the same
/// trajectory, byte for byte.
#[test]
fn a_fleet_runs_the_same_twice() {
    let args = [
        "run",
        "swap4",
        "--in-process",
        "--no-mcap",
        "--set",
        "duration_s=8",
    ];
    let (first, _) = run_into_tempdir(&args);
    let (second, _) = run_into_tempdir(&args);
    for id in 0..4 {
        let read = |dir: &tempfile::TempDir| {
            std::fs::read(dir.path().join(format!("robot{id}/trajectory.csv"))).unwrap()
        };
        assert!(read(&first) == read(&second), "robot {id} drove otherwise");
    }
}

/// Random fleets of two to four robots: no robot moves into another, and the report
/// counts every robot.
#[test]
fn random_fleets_have_no_contact_while_moving() {
    let (dir, out) = run_into_tempdir(&["fuzz", "--robots", "2..4", "--count", "6", "--seed", "3"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let csv = std::fs::read_to_string(dir.path().join("fleet_fuzz.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let (worlds, moving) = (column("world"), column("robot_contacts_moving"));
    let rows: Vec<Vec<&str>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect())
        .collect();
    let distinct: std::collections::BTreeSet<&str> = rows.iter().map(|r| r[worlds]).collect();
    assert_eq!(distinct.len(), 6, "{csv}");
    assert!(rows.len() >= 12, "two robots a world at least: {csv}");
    assert!(rows.iter().all(|r| r[moving] == "0"), "{csv}");
}

/// A fleet's bad input is refused before anything runs, naming the robot's key: two
/// robots on one spot, a robot inside an obstacle, a robot's own fault, what a fleet does
/// not run with, and a fleet outside `--in-process`.
#[test]
fn a_fleets_bad_input_names_the_robots_key() {
    let refused = |args: &[&str], key: &str| {
        let out = run(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", stderr(&out));
        assert!(stderr(&out).contains(key), "{args:?}: {}", stderr(&out));
    };
    let swap4 =
        |set: &str, key: &str| refused(&["run", "swap4", "--in-process", "--set", set], key);
    swap4("robots.1.start=[3.1, 0.0, 0.0]", "robots.1.start");
    swap4(
        "obstacles=[{x = 0.0, y = 3.0, radius = 0.5}]",
        "robots.1.start",
    );
    swap4("mpc.uncertainty_sigmas=0", "mpc.uncertainty_sigmas");
    swap4("lidar.rate_hz=10", "lidar");
    swap4("plant.disturbance_std=0.01", "plant.disturbance_std");
    swap4("robot.command_delay_s=0.02", "robot.command_delay_s");
    swap4(
        "robots.1.fault.mpc_delay_ms=-1",
        "robots.1.fault.mpc_delay_ms",
    );
    refused(
        &[
            "run",
            "warehouse",
            "--in-process",
            "--set",
            "perception.kind=track",
        ],
        "perception.kind",
    );
    refused(&["run", "swap4"], "--in-process");
    refused(&["fuzz", "--robots", "3..2"], "--robots");
}

/// A robot whose plans stop (its MPC fails from 3 s on, `[robots.fault]`): its DFL brakes
/// it to rest, the others go by where they see it and reach their goals past it, and no
/// robot touches another.
#[test]
fn a_robot_whose_plans_stop_brakes_to_rest_and_the_others_pass_it() {
    let (dir, out) = run_into_tempdir(&[
        "run",
        "swap4",
        "--in-process",
        "--no-mcap",
        "--set",
        "robots.1.fault.mpc_fail_samples=\"60..=2000\"",
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let fleet = summary(dir.path());
    assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
    assert_eq!(fleet["robot_contacts_at_rest"], 0, "{fleet}");
    for id in [0, 2, 3] {
        assert_eq!(fleet["robots"][id]["outcome"], "reached", "{fleet}");
    }
    assert_ne!(fleet["robots"][1]["outcome"], "reached", "{fleet}");
    let silent = std::fs::read_to_string(dir.path().join("robot1/trajectory.csv")).unwrap();
    let header: Vec<&str> = silent.lines().next().unwrap().split(',').collect();
    let last: Vec<&str> = silent.lines().last().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    assert_eq!(last[column("mode")], "brake", "{last:?}");
    assert_eq!(
        last[column("zeta")].parse::<f64>().unwrap(),
        0.0,
        "at rest: {last:?}"
    );
}
