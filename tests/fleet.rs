//! A fleet (docs/fleet.md): several robots, each its own pipeline, in one world.

use crate::common;

use common::agent::Agent;
use common::{events, leftovers, run, run_into_tempdir, stderr, summary, unique_prefix};

/// `swap4`: four robots exchange places through the circle's centre. Every robot reaches
/// its goal, none touches another, and the symmetric encounter is broken by robots giving
/// way, each a `gave_way` event in its record.
#[test]
fn swap4_every_robot_reaches_its_goal_without_contact_after_giving_way() {
    let _machine = common::machine_shared();
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

/// Asserts that each of the first `robots` robots of runs `a` and `b` has the same
/// `trajectory.csv` and `tracks.csv`, byte for byte.
fn assert_same_bytes(a: &tempfile::TempDir, b: &tempfile::TempDir, robots: usize) {
    for id in 0..robots {
        for file in ["trajectory.csv", "tracks.csv"] {
            let read = |dir: &tempfile::TempDir| {
                std::fs::read(dir.path().join(format!("robot{id}")).join(file)).unwrap()
            };
            assert!(read(a) == read(b), "robot {id}'s {file} differs");
        }
    }
}

/// `swap4` with `extra` arguments for its first 8 s (no robot reaches its goal by then),
/// in process and in lockstep across processes under `prefix` (which ends without a
/// goal reached and prints no error): the two runs' directories.
fn swap4_for_8_s_both_ways(extra: &[&str], prefix: &str) -> (tempfile::TempDir, tempfile::TempDir) {
    let short = [&["--set", "duration_s=8"][..], extra].concat();
    let in_process_args = [&["run", "swap4", "--in-process", "--no-mcap"][..], &short].concat();
    let (in_process, _) = run_into_tempdir(&in_process_args);
    let lockstep_args = [&["run", "swap4", "--prefix", prefix][..], &short].concat();
    let (lockstep, out) = run_into_tempdir(&lockstep_args);
    let code = out.status.code();
    assert_eq!(code, Some(1), "not reached in 8 s: {}", stderr(&out));
    assert!(!stderr(&out).contains("error"), "{}", stderr(&out));
    (in_process, lockstep)
}

/// In lockstep across processes (a plant, an estimator, a tracker, an MPC and a DFL per
/// robot, each robot's services under its id) a fleet drives every robot as the fleet in
/// process does, byte for byte: each robot's tracker hears the others over iceoryx2 from
/// before its tick only. The robots' `run.mcap` are merged into the run's. Every process
/// is stopped and nothing of the run is left in shared memory.
#[test]
fn in_lockstep_across_processes_a_fleet_drives_as_in_process_byte_for_byte() {
    let _machine = common::machine_shared();
    let prefix = unique_prefix("fleet");
    let (in_process, lockstep) = swap4_for_8_s_both_ways(&[], &prefix);
    assert_eq!(summary(lockstep.path())["mode"], "lockstep");
    // Both leave the fleet's scenario, the same.
    let fleet_scenario = |dir: &tempfile::TempDir| {
        std::fs::read_to_string(dir.path().join("scenario.toml")).expect("the fleet's scenario")
    };
    let scenario = fleet_scenario(&in_process);
    assert_eq!(scenario, fleet_scenario(&lockstep));
    assert_eq!(scenario.matches("[[robots]]").count(), 4, "{scenario}");
    // The robots' run.mcap merged into the run's.
    assert!(lockstep.path().join("run.mcap").exists());
    let mut pids = std::collections::BTreeSet::new();
    assert_same_bytes(&in_process, &lockstep, 4);
    for id in 0..4 {
        let robot = |dir: &tempfile::TempDir| dir.path().join(format!("robot{id}"));
        assert!(!robot(&lockstep).join("run.mcap").exists());
        let spawned: Vec<_> = (events(&robot(&lockstep)).into_iter())
            .filter(|e| e["event"] == "spawned")
            .collect();
        let roles: Vec<&str> = spawned
            .iter()
            .map(|e| e["role"].as_str().unwrap())
            .collect();
        assert_eq!(
            roles,
            ["plant", "estimator", "tracker", "mpc", "dfl"],
            "robot {id}"
        );
        pids.extend(spawned.iter().map(|e| e["pid"].as_u64().unwrap()));
    }
    assert_eq!(pids.len(), 20, "a process per role and robot");
    assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
}

/// `tests/fixtures/fleet-lidar.toml`: two robots passing, each with a lidar, a box on
/// robot 0's lane that no robot is told of, a pillar on the map.
const FLEET_LIDAR: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/fixtures/fleet-lidar.toml"
);

/// With a lidar each robot sees the box it was not told of, and goes by its plans for the
/// other robot: every track its lidar makes is the box's (the other robot's returns and
/// the known pillar's are left out). Both reach their goals without contact.
#[test]
fn with_a_lidar_each_robot_tracks_a_box_it_was_not_told_of_not_the_other_robot() {
    let _machine = common::machine_shared();
    let (dir, out) = run_into_tempdir(&["run", FLEET_LIDAR, "--in-process", "--no-mcap"]);
    assert!(out.status.success(), "{}", stderr(&out));
    let fleet = summary(dir.path());
    assert_eq!(fleet["reached"], 2, "{fleet}");
    assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
    for id in 0..2 {
        let tracks = std::fs::read_to_string(dir.path().join(format!("robot{id}/tracks.csv")))
            .expect("tracks.csv");
        let seen: Vec<[f64; 2]> = (tracks.lines().skip(1))
            .map(|line| line.split(',').collect::<Vec<_>>())
            .filter(|row| row[2].parse::<u32>().expect("an id") < protocol::FIRST_PEER)
            .map(|row| [3, 4].map(|c| row[c].parse::<f64>().expect("a number")))
            .collect();
        assert!(
            seen.len() > 100,
            "robot {id} tracked the box {} times",
            seen.len()
        );
        let off_the_box = seen.iter().find(|[x, y]| x.hypot(*y) > 0.3);
        assert_eq!(off_the_box, None, "robot {id}: a track not of the box");
    }
}

/// In lockstep across processes a fleet with lidars (a lidar process per robot, seeing
/// the other robots from their truths before its tick) drives every robot as in process,
/// byte for byte: the two robots of `tests/fixtures/fleet-lidar.toml`, and the eight of
/// `swap8` for half a second, each robot's truth taken by the seven others' trackers and
/// lidars. Nothing of either run is left in shared memory.
#[test]
fn in_lockstep_a_fleet_with_lidars_drives_as_in_process_byte_for_byte() {
    let _machine = common::machine_shared();
    let lidar = ["--set", "lidar.rate_hz=20"];
    for (scenario, robots, duration) in [
        (FLEET_LIDAR, 2, "duration_s=3"),
        ("swap8", 8, "duration_s=0.5"),
    ] {
        let short = [&lidar[..], &["--set", duration]].concat();
        let in_process = [&["run", scenario, "--in-process", "--no-mcap"][..], &short].concat();
        let (in_process, _) = run_into_tempdir(&in_process);
        let prefix = unique_prefix("fleetlidar");
        let args = [
            &["run", scenario, "--no-mcap", "--prefix", &prefix][..],
            &short,
        ]
        .concat();
        let (lockstep, out) = run_into_tempdir(&args);
        assert_eq!(
            out.status.code(),
            Some(1),
            "{scenario} not reached: {}",
            stderr(&out)
        );
        assert!(!stderr(&out).contains("error"), "{}", stderr(&out));
        assert_same_bytes(&in_process, &lockstep, robots);
        for id in 0..robots {
            let lidars = (events(&lockstep.path().join(format!("robot{id}"))).iter())
                .filter(|e| e["event"] == "spawned" && e["role"] == "lidar")
                .count();
            assert_eq!(lidars, 1, "{scenario}: robot {id}");
        }
        assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
    }
}

/// A person walking across `swap4`'s circle, 2 m off its centre at 1 m/s, whom no lidar
/// sees: each robot's tracker measures them from the truth.
const PERSON_ACROSS_SWAP4: &str =
    "obstacles=[{x = -5.0, y = 2.0, radius = 0.25, velocity = [1.0, 0.0]}]";

/// Without a lidar a fleet's robots track a person from the truth, as a robot alone does,
/// beside the other robots from their plans: every robot tracks the person (id 0) and
/// reaches its goal, none touches the person or another robot though one passes within
/// 0.6 m of them, and in lockstep across
/// processes every robot drives as in process, byte for byte.
#[test]
fn among_people_tracked_from_the_truth_a_fleet_keeps_clear_and_drives_as_in_process() {
    let _machine = common::machine_shared();
    let person = ["--set", PERSON_ACROSS_SWAP4];
    let args = [&["run", "swap4", "--in-process", "--no-mcap"][..], &person].concat();
    let (dir, out) = run_into_tempdir(&args);
    assert!(out.status.success(), "{}", stderr(&out));
    let fleet = summary(dir.path());
    assert_eq!(fleet["reached"], 4, "{fleet}");
    assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
    let mut nearest_m = f64::INFINITY;
    for id in 0..4 {
        let robot = dir.path().join(format!("robot{id}"));
        let own = summary(&robot);
        assert_eq!(
            (
                own["contacts_moving"].as_u64(),
                own["contacts_at_rest"].as_u64()
            ),
            (Some(0), Some(0))
        );
        let clearance_m = own["min_moving_clearance_m"].as_f64().unwrap();
        assert!(clearance_m > 0.0, "{own}");
        nearest_m = nearest_m.min(clearance_m);
        let tracks = std::fs::read_to_string(robot.join("tracks.csv")).expect("tracks.csv");
        let ids = |id: u32| {
            (tracks.lines().skip(1))
                .filter(|l| l.split(',').nth(2).and_then(|c| c.parse().ok()) == Some(id))
                .count()
        };
        assert!(
            ids(0) > 100,
            "robot {id} tracked the person {} times",
            ids(0)
        );
        let other = protocol::FIRST_PEER + u32::from(id == 0);
        assert_eq!(
            ids(0),
            ids(other),
            "robot {id}: the person and another robot, each tick"
        );
    }
    // The person crossed a robot's way: some robot had to keep clear of them.
    assert!(
        nearest_m < 0.6,
        "the person came no nearer than {nearest_m} m"
    );
    let prefix = unique_prefix("fleet-people");
    let (in_process, lockstep) = swap4_for_8_s_both_ways(&person, &prefix);
    assert_same_bytes(&in_process, &lockstep, 4);
    assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
}

/// Without `-q` and without a terminal, a fleet's run prints a progress line for the fleet
/// as it drives, in process and across processes: the time (rising line by line), the
/// robots at their goals (none in the first 4 s of `swap4`, some before the end of the
/// whole run in process), the deadlines their records missed (none before robot 1's MPC
/// fails at 3 s, some after, never more than the summary's, and named as robot 1's),
/// their clearance to each other and their contacts, all before the end table.
#[test]
fn a_fleets_run_prints_the_fleets_progress_in_both_executors() {
    let _machine = common::machine_shared();
    let prefix = unique_prefix("fleetline");
    let whole: (&[&str], &str) = (&["--in-process"], "40.0");
    let first_4_s: (&[&str], &str) = (&["--prefix", &prefix, "--set", "duration_s=4"], "4.0");
    let fails_at_3_s = ["--set", "robots.1.fault.mpc_fail_samples=\"60..=2000\""];
    for (executor, duration) in [whole, first_4_s] {
        let dir = tempfile::tempdir().unwrap();
        let out = (common::scmpc())
            .args(["run", "swap4", "--no-mcap", "--out"])
            .arg(dir.path())
            .args(executor)
            .args(fails_at_3_s)
            .env("SCMPC_PROGRESS_S", "0.02")
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let lines: Vec<&str> = (stdout.lines())
            .filter(|l| l.starts_with("t ") && l.contains(" | at their goals "))
            .collect();
        assert!(lines.len() >= 2, "{executor:?}: {stdout}");
        let field = |line: &str, after: &str, to: char| -> f64 {
            let rest = &line[line.find(after).unwrap() + after.len()..];
            rest[..rest.find(to).unwrap()].trim().parse().unwrap()
        };
        let time = |l: &str| field(l, "t ", '/');
        let reached = |l: &str| field(l, "goals ", 'o');
        let misses = |l: &str| field(l, "deadline misses ", ' ');
        let misses_of_robot_1 = |l: &str| match l.contains("(robot 1: ") {
            true => field(l, "(robot 1: ", ')'),
            false => 0.0,
        };
        assert!(
            lines.windows(2).all(|w| time(w[0]) <= time(w[1])),
            "{executor:?}: {lines:?}"
        );
        assert!(
            lines.windows(2).all(|w| misses(w[0]) <= misses(w[1])),
            "{executor:?}: {lines:?}"
        );
        let by_robot: Vec<u64> = (summary(dir.path())["robots"].as_array().unwrap().iter())
            .map(|r| r["deadline_misses"].as_u64().unwrap())
            .collect();
        let missed: u64 = by_robot.iter().sum();
        // Only robot 1's MPC fails, so the misses named are robot 1's.
        for line in &lines {
            assert_eq!(
                misses_of_robot_1(line),
                misses(line),
                "{executor:?}: {line}"
            );
            assert!(misses_of_robot_1(line) <= by_robot[1] as f64, "{line}");
        }
        for line in &lines {
            let (t, n) = (time(line), misses(line));
            assert!(t >= 3.0 || n == 0.0, "{executor:?}: {line}");
            assert!(n <= missed as f64, "{executor:?}: {line}, {missed} in all");
        }
        assert!(misses(lines[lines.len() - 1]) > 0.0, "{lines:?}");
        for line in &lines {
            assert!(
                line.contains(&format!(" / {duration} s | at their goals "))
                    && line.contains(" of 4 | deadline misses ")
                    && line.contains(" | robot-robot clearance ")
                    && line.ends_with("| contacts 0 moving, 0 at rest"),
                "{executor:?}: {line}"
            );
        }
        let most = lines.iter().map(|l| reached(l)).fold(0.0, f64::max);
        match duration {
            "4.0" => assert_eq!(most, 0.0, "{lines:?}"),
            _ => assert!((1.0..=4.0).contains(&most), "{lines:?}"),
        }
        let table = stdout.find("fleet swap4").expect("the end table");
        assert!(stdout.rfind(lines[lines.len() - 1]).unwrap() < table);
    }
}

/// Random fleets of two to four robots: no robot moves into another, and the report
/// counts every robot. Seen through a lidar (`--perception lidar`) they are the same
/// worlds, some of their obstacles boxes no robot is told of, and no robot moves into
/// another or into a box. With people on the robots' ways (`--people 1`) they are the same
/// fleets among the same obstacles at rest, and no robot moves into a person.
#[test]
fn random_fleets_have_no_contact_while_moving_with_or_without_a_lidar_or_people() {
    let _machine = common::machine_shared();
    let batch = |more: &[&str]| {
        let args = [
            &["fuzz", "--robots", "2..4", "--count", "6", "--seed", "3"][..],
            more,
        ]
        .concat();
        let (dir, out) = run_into_tempdir(&args);
        assert!(out.status.success(), "{more:?}: {}", stderr(&out));
        std::fs::read_to_string(dir.path().join("fleet_fuzz.csv")).unwrap()
    };
    let (truth, lidar) = (batch(&[]), batch(&["--perception", "lidar"]));
    let people = batch(&["--people", "1"]);
    let header: Vec<&str> = truth.lines().next().unwrap().split(',').collect();
    let column = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows = |csv: &str| -> Vec<Vec<String>> {
        (csv.lines().skip(1))
            .map(|l| l.split(',').map(str::to_owned).collect())
            .collect()
    };
    let (truth_rows, lidar_rows, people_rows) = (rows(&truth), rows(&lidar), rows(&people));
    let worlds = |rows: &[Vec<String>], of: &[&str]| -> Vec<Vec<String>> {
        let columns: Vec<usize> = of.iter().map(|c| column(c)).collect();
        (rows.iter())
            .map(|r| columns.iter().map(|&c| r[c].clone()).collect())
            .collect()
    };
    let drawn = ["world", "robot", "robots", "obstacles", "v_max", "radius_m"];
    assert_eq!(worlds(&truth_rows, &drawn), worlds(&lidar_rows, &drawn));
    assert_eq!(worlds(&truth_rows, &drawn), worlds(&people_rows, &drawn));
    let count = |rows: &[Vec<String>], name: &str| -> usize {
        (rows.iter())
            .map(|r| r[column(name)].parse::<usize>().unwrap())
            .sum()
    };
    assert_eq!(count(&truth_rows, "people"), 0, "{truth}");
    assert!(count(&people_rows, "people") > 0, "{people}");
    let distinct: std::collections::BTreeSet<&str> = truth_rows
        .iter()
        .map(|r| r[column("world")].as_str())
        .collect();
    assert_eq!(distinct.len(), 6, "{truth}");
    assert!(
        truth_rows.len() >= 12,
        "two robots a world at least: {truth}"
    );
    assert_eq!(count(&truth_rows, "unmapped"), 0, "{truth}");
    assert!(count(&lidar_rows, "unmapped") > 0, "{lidar}");
    assert_eq!(count(&people_rows, "unmapped"), 0, "{people}");
    let batches = [
        (&truth_rows, &truth),
        (&lidar_rows, &lidar),
        (&people_rows, &people),
    ];
    for (rows, csv) in batches {
        let (moving, outcome) = (column("robot_contacts_moving"), column("outcome"));
        assert!(rows.iter().all(|r| r[moving] == "0"), "{csv}");
        assert!(rows.iter().all(|r| r[outcome] != "collided"), "{csv}");
    }
}

/// A fleet's bad input is refused before anything runs, naming the robot's key: two
/// robots on one spot, a robot inside an obstacle, a robot's own fault, what a fleet does
/// not run with.
#[test]
fn a_fleets_bad_input_names_the_robots_key() {
    let _machine = common::machine_shared();
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
    swap4("plant.disturbance_std=0.01", "plant.disturbance_std");
    swap4(
        "plant.max_wheel_speed_rad_s=20",
        "plant.max_wheel_speed_rad_s",
    );
    swap4("robot.command_delay_s=0.02", "robot.command_delay_s");
    swap4(
        "robots.1.fault.mpc_delay_ms=-1",
        "robots.1.fault.mpc_delay_ms",
    );
    refused(&["fuzz", "--robots", "3..2"], "--robots");
    refused(&["fuzz", "--robots", "2..3", "--people", "1.5"], "--people");
    swap4("robots.1.host=\"b c\"", "robots.1.host");
    swap4("robots.1.host=orchestrator", "robots.1.host");
    swap4("robots.1.host_roles=\"pipeline\"", "robots.1.host_roles");
    swap4("robots.1.host_roles=\"whole\"", "robots.1.host_roles");
    swap4("robots.1.fault.link_loss=0.1", "robots.1.fault");
    swap4("hosts.mpc=\"b\"", "hosts");
    refused(
        &["run", "swap4", "--set", "robots.1.host=\"b\""],
        "host `b`: no endpoint",
    );
}

/// A robot whose plans stop (its MPC fails from 3 s on, `[robots.fault]`): its DFL brakes
/// it to rest, the others go by where they see it and reach their goals past it, and no
/// robot touches another.
#[test]
fn a_robot_whose_plans_stop_brakes_to_rest_and_the_others_pass_it() {
    let _machine = common::machine_shared();
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

/// `tests/fixtures/fleet-across-hosts.toml`: three robots, robots 1 and 2 on hosts `b` and
/// `c`, each an agent on loopback; the `scmpc run` arguments that place them there.
fn across_hosts(b: &Agent, c: &Agent) -> Vec<String> {
    let fixture = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/fleet-across-hosts.toml"
    );
    [
        "run",
        fixture,
        "--no-mcap",
        "--host",
        &format!("b={}", b.endpoint),
        "--host",
        &format!("c={}", c.endpoint),
    ]
    .map(String::from)
    .to_vec()
}

/// Runs `across_hosts`'s fleet (`args`) under `prefix` with `extra` into `dir`, and
/// SIGKILLs agent `c` (robot 2's) once the run is 2 s in; returns the run's exit code.
fn run_killing_agent_c(
    args: &[String],
    c: &mut Agent,
    dir: &std::path::Path,
    prefix: &str,
    extra: &[&str],
) -> Option<i32> {
    let args: Vec<&str> = args[1..].iter().map(String::as_str).collect();
    let mut child = common::spawn_run(dir, &[&args[..], &["--prefix", prefix], extra].concat());
    common::wait_for_pid(&dir.join("robot2"), "mpc");
    common::SimulatedClock::of(prefix).wait_until(2.0);
    c.child.kill().unwrap();
    c.child.wait().unwrap();
    child.wait().unwrap().code()
}

/// In lockstep with robots 1 and 2 on hosts of their own (robot 1's planning, robot 2's
/// whole pipeline but its plant there, every other robot's truth, estimate and plan
/// carried to them over Zenoh), every robot drives as the fleet in process does, byte for
/// byte.
#[test]
fn in_lockstep_robots_on_other_hosts_drive_as_in_process_byte_for_byte() {
    let _machine = common::machine_shared();
    let (b, c) = (Agent::plain("b"), Agent::plain("c"));
    let args = across_hosts(&b, &c);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let short = ["--set", "duration_s=8"];
    let (in_process, _) = run_into_tempdir(&[&args[..], &["--in-process"], &short].concat());
    let (lockstep, out) = run_into_tempdir(&[&args[..], &short].concat());
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(!stderr(&out).contains("error"), "{}", stderr(&out));
    assert_same_bytes(&in_process, &lockstep, 3);
    let s = summary(&lockstep.path().join("robot1"));
    assert_eq!(s["hosts"]["mpc"], "b", "{s}");
    assert_eq!(s["hosts"]["tracker"], "b", "{s}");
    assert!(
        s["hosts"]["dfl"].is_null(),
        "robot 1's inner loop runs here: {s}"
    );
    assert!(s["links"]["b"]["host_bridge"]["received"].as_u64().unwrap() > 1000);
    let s = summary(&lockstep.path().join("robot2"));
    for role in ["estimator", "tracker", "mpc", "dfl"] {
        assert_eq!(s["hosts"][role], "c", "{s}");
    }
    let robot0 = summary(&lockstep.path().join("robot0"));
    assert!(robot0["hosts"].is_null(), "robot 0 runs here: {robot0}");
}

/// Robots 1 and 2 whose planning runs on one host: its agent joins the run once for each,
/// with processes, an iceoryx2 prefix and a bridge of each one's own, and each robot's
/// links are under a run key of its own, so neither robot takes the other's samples. In
/// lockstep every robot drives as the fleet in process, byte for byte; both joins end with
/// the run, and the agent serves the next run.
#[test]
fn in_lockstep_two_robots_on_one_host_drive_as_in_process_byte_for_byte() {
    let _machine = common::machine_shared();
    let b = Agent::plain("b");
    let mut args = across_hosts(&b, &b);
    args.truncate(args.len() - 2); // no host `c`
    let args: Vec<&str> = (args.iter().map(String::as_str))
        .chain(["--set", "robots.2.host=\"b\""])
        .collect();
    let short = ["--set", "duration_s=8"];
    let (in_process, _) = run_into_tempdir(&[&args[..], &short, &["--in-process"]].concat());
    let prefix = unique_prefix("fleetonehost");
    let (lockstep, out) = run_into_tempdir(&[&args[..], &short, &["--prefix", &prefix]].concat());
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(!stderr(&out).contains("error"), "{}", stderr(&out));
    assert_same_bytes(&in_process, &lockstep, 3);
    for id in [1, 2] {
        let s = summary(&lockstep.path().join(format!("robot{id}")));
        assert_eq!(s["hosts"]["mpc"], "b", "{s}");
        let received = s["links"]["b"]["host_bridge"]["received"].as_u64().unwrap();
        assert!(received > 1000, "robot {id}'s link to `b`: {s}");
    }
    for robot in [1, 2] {
        b.wait_for_line(&format!(
            "(robot {robot}) ended (the orchestrator ended it)"
        ));
    }
    assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
    b.assert_left_nothing(std::time::Duration::from_secs(5));
    let next = ["--set", "duration_s=1"];
    let (_, out) = run_into_tempdir(&[&args[..], &next].concat());
    assert!(!stderr(&out).contains("error"), "{}", stderr(&out));
}

/// In real time every robot's clock starts at one tick 0, and robots 0 and 1 (robot 1 on
/// host `b`) exchange sides, passing each other, without a deadline missed but in a stall
/// of the machine. Robot 2's agent is killed (SIGKILL) 2 s in, its DFL with it: its
/// plant's watchdog brakes it to rest (`plant.command_timeout_s`) before its record ends
/// `aborted`, and the other two pass it to their goals without contact. Nothing of the
/// run is left.
#[test]
fn in_real_time_a_robot_on_another_host_swaps_without_a_miss_and_one_whose_agent_dies_brakes_to_rest()
 {
    common::until_judged(|machine| {
        let (b, mut c) = (Agent::plain("b"), Agent::plain("c"));
        let args = across_hosts(&b, &c);
        let prefix = unique_prefix("fleethosts");
        let dir = tempfile::tempdir().unwrap();
        let code = run_killing_agent_c(&args, &mut c, dir.path(), &prefix, &["--mode", "realtime"]);
        let fleet = summary(dir.path());
        assert_eq!(code, Some(1), "robot 2 cannot reach: {fleet}");
        assert_eq!(fleet["reached"], 2, "{fleet}");
        assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
        assert_eq!(fleet["robot_contacts_at_rest"], 0, "{fleet}");
        let mut ticks_0 = std::collections::BTreeSet::new();
        for id in 0..3 {
            let robot = dir.path().join(format!("robot{id}"));
            let events = events(&robot);
            ticks_0.insert(common::stalls::tick0_ns(&events));
            if id < 2 {
                let s = summary(&robot);
                assert_eq!(s["outcome"], "reached", "{s}");
                assert_eq!(s["solver_failures"], 0, "{s}");
                machine.judge(&events)?;
            }
        }
        assert_eq!(ticks_0.len(), 1, "one tick 0 for every robot: {ticks_0:?}");
        let robot2 = dir.path().join("robot2");
        let s = summary(&robot2);
        assert_eq!(s["outcome"], "aborted", "{s}");
        assert_eq!(s["hosts"]["mpc"], "c", "where it ran, though lost: {s}");
        let ev = events(&robot2);
        let at = |event: &str| ev.iter().position(|e| e["event"] == event);
        assert!(
            at("host_lost").is_some() && at("host_lost") < at("braking_to_rest"),
            "{ev:#?}"
        );
        assert!(at("host_lost") < at("command_timeout"), "{ev:#?}");
        let trajectory = common::csv(&robot2.join("trajectory.csv"));
        assert!(
            trajectory[trajectory.len() - 10..]
                .iter()
                .all(|row| row["mode"] == "watchdog"),
            "braked by the plant's watchdog: {:#?}",
            &trajectory[trajectory.len() - 10..]
        );
        let last = &trajectory[trajectory.len() - 10..];
        let moved = |a: &std::collections::HashMap<String, String>| {
            let b = &last[9];
            (common::num(a, "x") - common::num(b, "x"))
                .hypot(common::num(a, "y") - common::num(b, "y"))
        };
        assert!(
            last.iter().all(|row| moved(row) < 1e-9),
            "robot 2 still moving: {last:#?}"
        );
        assert!(moved(&trajectory[0]) > 0.2, "robot 2 never drove");
        assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
        c.assert_left_nothing(std::time::Duration::from_secs(3));
        b.assert_left_nothing(std::time::Duration::from_secs(3));
        Ok(())
    })
}

/// With `supervision.failover = "local"`, a fleet robot whose agent is SIGKILLed (robot 2,
/// its estimator, tracker, MPC and DFL on host `c`) has them all started again on the
/// orchestrator's host, and reaches its goal; so do the others, with no contact. In
/// lockstep: the kill comes at a simulated time, and the clock waits for the replacements
/// (the new estimator starts its filter without the lost DFL's last command).
#[test]
fn with_failover_local_a_robot_whose_agent_dies_is_planned_for_here_and_reaches_its_goal() {
    let _machine = common::machine_shared();
    let (b, mut c) = (Agent::plain("b"), Agent::plain("c"));
    let args = across_hosts(&b, &c);
    let prefix = unique_prefix("fleetfailover");
    let dir = tempfile::tempdir().unwrap();
    let local = ["--set", "supervision.failover=local"];
    let code = run_killing_agent_c(&args, &mut c, dir.path(), &prefix, &local);
    assert_eq!(
        code,
        Some(0),
        "every robot reaches: {}",
        summary(dir.path())
    );
    let fleet = summary(dir.path());
    assert_eq!(fleet["reached"], 3, "{fleet}");
    assert_eq!(fleet["robot_contacts_moving"], 0, "{fleet}");
    assert_eq!(fleet["robot_contacts_at_rest"], 0, "{fleet}");
    let robot2 = dir.path().join("robot2");
    let ev = events(&robot2);
    assert!(
        ev.iter()
            .any(|e| e["event"] == "host_lost" && e["host"] == "c"),
        "{ev:#?}"
    );
    for role in ["estimator", "tracker", "mpc", "dfl"] {
        let failed_over = ev
            .iter()
            .find(|e| e["event"] == "failed_over" && e["role"] == role)
            .unwrap_or_else(|| panic!("the {role} did not fail over: {ev:#?}"));
        assert!(failed_over["host"].is_null(), "{failed_over}");
    }
    assert_eq!(summary(&robot2)["hosts"]["mpc"], "c", "where it began");
    assert!(leftovers(&prefix).is_empty(), "{:?}", leftovers(&prefix));
    c.assert_left_nothing(std::time::Duration::from_secs(3));
    b.assert_left_nothing(std::time::Duration::from_secs(3));
}
