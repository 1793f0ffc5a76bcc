//! A world that moves (issue 45): obstacles with velocities, the tracker process, the
//! MPC's CBFs on the discs its tracks predict, and contacts judged against the obstacles'
//! true positions.

use crate::common;

use common::{csv, events, num, run, stderr, summary};
use std::path::Path;

/// Runs `args` (after `run`) into `dir`; its summary.
fn run_into(dir: &Path, args: &[&str]) -> serde_json::Value {
    let out = run(&[&["run", "--out", dir.to_str().unwrap()], args].concat());
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    summary(dir)
}

/// The path of `tests/fixtures/<name>`.
fn fixture(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name);
    path.to_str().unwrap().to_owned()
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The tracks follow the crossing person: a row every perception tick (50 ms) of the run
/// (which ends at the goal, after more than 10 s), after the first second the estimate
/// within a few sigma of the truth, and the velocity near the person's 1 m/s.
fn assert_tracks_follow_the_truth(dir: &Path) {
    let rows = csv(&dir.join("tracks.csv"));
    let last_s = num(rows.last().unwrap(), "t");
    assert!(
        last_s > 10.0 && rows.len() as f64 >= last_s / 0.05,
        "{} rows over {last_s} s",
        rows.len()
    );
    for row in rows.iter().filter(|r| num(r, "t") >= 1.0) {
        let error = (num(row, "x") - num(row, "x_true")).hypot(num(row, "y") - num(row, "y_true"));
        assert!(error <= 4.0 * num(row, "sigma_p_m").max(1e-3), "{row:?}");
        assert!((num(row, "vy") - 1.0).abs() < 0.3, "{row:?}");
    }
}

#[test]
fn crossing_is_reached_without_contact_in_process_and_identically_in_lockstep() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let (inprocess, lockstep) = (dir.path().join("in-process"), dir.path().join("lockstep"));
    let s = run_into(&inprocess, &["crossing", "--in-process"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert_eq!(s["contacts_moving"], 0);
    assert_eq!(s["contacts_at_rest"], 0);
    assert!(s["min_moving_clearance_m"].as_f64().unwrap() > 0.0, "{s}");
    assert_tracks_follow_the_truth(&inprocess);

    let s = run_into(&lockstep, &["crossing"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert!(s["pids"]["tracker"].as_u64().is_some(), "{s}");
    for file in ["trajectory.csv", "tracks.csv"] {
        assert!(
            read(&inprocess.join(file)) == read(&lockstep.join(file)),
            "{file} differs between in process and lockstep"
        );
    }
}

#[test]
fn a_box_and_people_not_in_the_map_are_seen_and_kept_clear_of_alike_in_process_and_in_lockstep() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let (inprocess, lockstep) = (dir.path().join("in-process"), dir.path().join("lockstep"));
    let s = run_into(&inprocess, &["unmapped", "--in-process"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert_eq!(s["contacts_moving"], 0, "{s}");
    assert_eq!(s["contacts_at_rest"], 0, "{s}");
    // The box is on the straight way: the robot drove round what it saw of it.
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0, "{s}");
    let rows = csv(&inprocess.join("tracks.csv"));
    for (x, y) in [(0.5, f64::NAN), (2.0, 1.3), (-1.0, 0.2)] {
        let seen = rows.iter().any(|r| {
            let error = (num(r, "x") - num(r, "x_true")).hypot(num(r, "y") - num(r, "y_true"));
            num(r, "x_true") == x && (y.is_nan() || num(r, "y_true") == y) && error < 0.5
        });
        assert!(seen, "no track within 0.5 m of the obstacle at x = {x}");
    }
    // Judged against the truth: every track on an obstacle, none of the three missed.
    let p = &s["perception"];
    assert!(p["tracks_born"].as_u64() >= Some(3), "{p}");
    assert_eq!(
        (&p["false_tracks"], &p["missed_obstacles"]),
        (&0.into(), &0.into()),
        "{p}"
    );

    let s = run_into(&lockstep, &["unmapped"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert!(s["pids"]["lidar"].as_u64().is_some(), "{s}");
    for file in ["trajectory.csv", "tracks.csv"] {
        assert!(
            read(&inprocess.join(file)) == read(&lockstep.join(file)),
            "{file} differs between in process and lockstep"
        );
    }
}

#[test]
fn a_lidar_that_sees_too_little_too_late_stops_the_robot_short_of_the_box_by_its_free_range_alone()
{
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let (checked, unchecked) = (dir.path().join("checked"), dir.path().join("unchecked"));
    let short_sight = ["unmapped", "--in-process", "--set", "lidar.range_max_m=0.3"];
    // Where a run ended, from the box's centre ((-1, 0.2), radius 0.4), m.
    let to_box = |dir: &Path| {
        let last = csv(&dir.join("trajectory.csv")).pop().unwrap();
        (num(&last, "x") + 1.0).hypot(num(&last, "y") - 0.2)
    };
    let s = run_into(&checked, &short_sight);
    assert_eq!(s["contacts_moving"], 0, "{s}");
    // The people came near in plain sight and were never tracked.
    assert!(
        s["perception"]["missed_obstacles"].as_u64() >= Some(1),
        "{s}"
    );
    let braked = (events(&checked).iter())
        .any(|e| e["event"] == "safety_intervention" && e["reason"] == "free_range");
    assert!(braked, "no free_range intervention");
    assert!(
        to_box(&checked) > 0.4,
        "ended {} m from the box's centre",
        to_box(&checked)
    );

    // Without the DFL's checks, the same lidar lets the robot into the box.
    let unchecked_run = [&short_sight[..], &["--set", "dfl.gatekeeper=false"]].concat();
    let s = run_into(&unchecked, &unchecked_run);
    assert_eq!(s["outcome"], "collided", "{s}");
    assert!(
        to_box(&unchecked) <= 0.4,
        "ended {} m from the box's centre",
        to_box(&unchecked)
    );
}

#[test]
fn the_phantoms_slow_the_robot_by_a_pillar_a_person_steps_out_from_as_its_lidar_asks_alike_in_process_and_in_lockstep()
 {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let (inprocess, lockstep) = (dir.path().join("in-process"), dir.path().join("lockstep"));
    let s = run_into(&inprocess, &["occluded", "--in-process"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert_eq!(
        (
            s["contacts_moving"].as_u64(),
            s["contacts_at_rest"].as_u64()
        ),
        (Some(0), Some(0)),
        "{s}"
    );
    // The phantoms (on by default) were in the tracks the MPC and the DFL took.
    let phantoms = csv(&inprocess.join("tracks.csv"))
        .iter()
        .filter(|r| num(r, "obstacle") >= f64::from(protocol::FIRST_PHANTOM))
        .count();
    assert!(phantoms > 0, "no phantom in tracks.csv");
    let s = run_into(&lockstep, &["occluded"]);
    assert_eq!(s["outcome"], "reached", "{s}");
    for file in ["trajectory.csv", "tracks.csv"] {
        assert!(
            read(&inprocess.join(file)) == read(&lockstep.join(file)),
            "{file} differs between in process and lockstep"
        );
    }

    // A lidar at 1 Hz: its phantoms stand for 1.05 s, and the robot must be able to stop
    // from where it will be by then before anything stepping out now could reach it, so
    // it passes the pillar slower than with the unseen assumed empty. (At 2 Hz the
    // phantoms, behind the pillar of the map, not in it, hardly bind.)
    let fastest_by_the_pillar = |phantoms: bool| {
        let out = dir.path().join(format!("1-hz-{phantoms}"));
        let set = format!("perception.phantoms={phantoms}");
        let sets = ["--set", "lidar.rate_hz=1", "--set", &set];
        let s = run_into(&out, &[&["occluded", "--in-process"][..], &sets].concat());
        assert_eq!(s["contacts_moving"], 0, "{s}");
        csv(&out.join("trajectory.csv"))
            .iter()
            .filter(|r| (-1.5..0.5).contains(&num(r, "x")))
            .map(|r| num(r, "zeta"))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let (careful, blind) = (fastest_by_the_pillar(true), fastest_by_the_pillar(false));
    assert!(
        careful + 0.1 < blind,
        "by the pillar at up to {careful} m/s with phantoms, {blind} m/s without"
    );
}

#[test]
fn a_person_stepping_out_from_behind_a_pillar_touches_the_moving_robot_only_without_phantoms() {
    // Issue 56: the lidar fuzz's world 748 of seed 1, drawn without phantoms, where the
    // person comes out of the pillar's shadow into a robot at 0.89 m/s. Since the tracker
    // fits a face's circle behind it (da9e1f7) the person is seen in time at 5 Hz and up
    // without phantoms; with a 4 Hz lidar only the phantoms save the robot.
    let _machine = common::machine_shared();
    let world = &fixture("fuzz-lidar-seed-1-world-748.toml");
    let dir = tempfile::tempdir().unwrap();
    let contacts = |phantoms: bool| {
        let out = dir.path().join(format!("phantoms-{phantoms}"));
        let set = format!("perception.phantoms={phantoms}");
        let args = [
            world,
            "--in-process",
            "--set",
            &set,
            "--set",
            "lidar.rate_hz=4",
        ];
        let s = run_into(&out, &args);
        s["contacts_moving"].as_u64().unwrap()
    };
    assert_eq!(contacts(false), 1, "without phantoms");
    assert_eq!(contacts(true), 0, "with phantoms");
}

/// Runs the lidar fuzz's world `file` in process, asserts it reached with no contact while
/// moving, and returns the tracks on the one obstacle not in the map (`x_true` known). The
/// caller holds the machine.
fn lidar_world_reached_untouched(file: &str) -> Vec<std::collections::HashMap<String, String>> {
    let dir = tempfile::tempdir().unwrap();
    let s = run_into(dir.path(), &[&fixture(file), "--in-process"]);
    assert_eq!(
        (s["outcome"].as_str(), &s["contacts_moving"]),
        (Some("reached"), &0.into()),
        "{s}"
    );
    let tracks = csv(&dir.path().join("tracks.csv"));
    tracks
        .into_iter()
        .filter(|t| num(t, "x_true").is_finite())
        .collect()
}

#[test]
fn a_box_the_lidar_sees_is_passed_not_circled_at_the_distance_of_the_fastest_stop() {
    let _machine = common::machine_shared();
    // Issue 56: the lidar fuzz's world 5 of seed 1. The box's track stands still; swept
    // over the fastest stop the input box reaches its disc held the robot 4 m off.
    let on_the_box = lidar_world_reached_untouched("fuzz-lidar-seed-1-world-5.toml");
    assert!(!on_the_box.is_empty(), "the box was seen");
}

#[test]
fn a_goal_beside_a_box_the_lidar_sees_is_reached_not_circled_on_the_spot() {
    let _machine = common::machine_shared();
    // Issue 56: the lidar fuzz's world 129 of seed 1 (the fixture's header).
    let on_the_box = lidar_world_reached_untouched("fuzz-lidar-seed-1-world-129.toml");
    // The box was seen, and its track stood still.
    let last = on_the_box.last().expect("the box was seen");
    let speed = num(last, "vx").hypot(num(last, "vy")) + num(last, "sigma_v_m_s");
    assert!(speed < protocol::STANDING_SPEED_M_S, "{last:?}");
}

#[test]
fn fuzz_world_74_of_seed_5_ends_untouched_while_moving_in_process_and_identically_in_lockstep() {
    // Issue 54: a person walked at a robot at rest beside an obstacle, every plan was
    // refused or infeasible for a second, and the DFL, taking the choice that kept the
    // most clearance, was touched reversing at 0.25 m/s.
    let _machine = common::machine_shared();
    let world = &fixture("fuzz-seed-5-world-74.toml");
    let dir = tempfile::tempdir().unwrap();
    let (inprocess, lockstep) = (dir.path().join("in-process"), dir.path().join("lockstep"));
    let s = run_into(&inprocess, &[world, "--in-process"]);
    assert_eq!(s["contacts_moving"], 0, "{s}");
    let outcome = s["outcome"].as_str().unwrap();
    let last = csv(&inprocess.join("trajectory.csv")).pop().unwrap();
    assert!(
        outcome == "reached" || (outcome != "collided" && num(&last, "zeta").abs() < 1e-3),
        "reached or stopped: {s}, at the end {last:?}"
    );
    let s = run_into(&lockstep, &[world]);
    assert_eq!(
        (s["outcome"].as_str(), &s["contacts_moving"]),
        (Some(outcome), &0.into()),
        "{s}"
    );
    assert!(
        read(&inprocess.join("trajectory.csv")) == read(&lockstep.join("trajectory.csv")),
        "trajectory.csv differs between in process and lockstep"
    );
}

#[test]
fn fuzz_world_372_of_seed_1_stops_out_of_the_persons_way() {
    // Issue 54: a person walks head-on at the robot; with passive safety alone its plans
    // stopped in the person's way and the person walked into it at rest. With the stop
    // kept out of the person's way for `mpc.rest_lookahead_s` more, it is not touched.
    // (Since the escape plan's rows sweep the person over the plan's own stop exactly,
    // 2026-11-30, passive safety alone is not walked into here either: docs/safety.md.)
    let _machine = common::machine_shared();
    let world = &fixture("fuzz-seed-1-world-372.toml");
    let dir = tempfile::tempdir().unwrap();
    let s = run_into(dir.path(), &[world, "--in-process"]);
    assert_eq!(
        (&s["outcome"], &s["contacts_moving"], &s["contacts_at_rest"]),
        (&"reached".into(), &0.into(), &0.into()),
        "{s}"
    );
}

#[test]
fn the_dfls_check_on_the_tracks_alone_keeps_an_mpc_blind_to_obstacles_off_the_crossing_person() {
    // The same world with an MPC that ignores every obstacle and drives straight at the
    // goal (no planner, so it meets the person): the DFL's check refuses its plans into
    // the discs the tracks predict. Without the check too, the robot runs into the person:
    // what the tracks keep it out of.
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let blind = [
        "crossing",
        "--in-process",
        "--set",
        "fault.mpc_ignore_obstacles=true",
        "--set",
        "planner.kind=none",
    ];
    let checked = dir.path().join("checked");
    let s = run_into(&checked, &blind);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert_eq!(s["contacts_moving"], 0, "{s}");
    assert!(s["min_moving_clearance_m"].as_f64().unwrap() > 0.0, "{s}");
    let refused = events(&checked)
        .iter()
        .filter(|e| e["event"] == "safety_intervention" && e["reason"] == "plan_refused")
        .count();
    assert!(refused > 0, "no plan refused");

    let unchecked = [&blind[..], &["--set", "dfl.gatekeeper=false"]].concat();
    let s = run_into(&dir.path().join("unchecked"), &unchecked);
    assert_eq!(s["outcome"], "collided", "{s}");
    assert_eq!(s["contacts_moving"], 1);
    assert!(s["min_moving_clearance_m"].as_f64().unwrap() < 0.0, "{s}");
}

#[test]
fn a_world_at_rest_runs_no_tracker() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let s = run_into(dir.path(), &["--set", "duration_s=1"]);
    assert!(s["pids"]["dfl"].as_u64().is_some(), "{s}");
    assert!(s["pids"].get("tracker").is_none(), "{s}");
    assert!(s["min_moving_clearance_m"].is_null(), "{s}");
    assert!(!dir.path().join("tracks.csv").exists());
}

#[test]
fn a_robot_at_rest_gets_out_of_the_way_of_an_obstacle_coming_at_it() {
    // The robot's goal is its start: it is held there, and a person walks at it.
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("walk-through.toml");
    std::fs::write(
        &file,
        "name = \"walk-through\"\nduration_s = 6.0\n\n[robot]\nstart = [0.0, 0.0, 0.0]\n\
         goal = [0.0, 0.0]\nhold_at_goal = true\n\n[[obstacles]]\nx = -3.0\ny = 0.0\nradius = 0.3\n\
         velocity = [1.0, 0.0]\n",
    )
    .unwrap();
    let run_dir = dir.path().join("run");
    let s = run_into(&run_dir, &[file.to_str().unwrap(), "--in-process"]);
    assert_eq!(s["contacts_at_rest"], 0, "{s}");
    assert_eq!(s["contacts_moving"], 0, "{s}");
    assert!(s["min_moving_clearance_m"].as_f64().unwrap() > 0.0, "{s}");
    // Where the person passes at t = 3 s, the robot no longer is.
    let rows = csv(&run_dir.join("trajectory.csv"));
    let at_3_s = rows.iter().find(|r| num(r, "t") >= 3.0).unwrap();
    assert!(num(at_3_s, "x").hypot(num(at_3_s, "y")) > 0.3, "{at_3_s:?}");
}

#[test]
fn dropped_measurements_grow_the_tracks_uncertainty_and_the_robot_still_keeps_clear() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let s = run_into(
        dir.path(),
        &[
            "crossing",
            "--in-process",
            "--set",
            "fault.tracker_drop_samples=\"40..=60\"",
        ],
    );
    assert_eq!(s["outcome"], "reached", "{s}");
    assert_eq!(s["contacts_moving"], 0);
    let rows = csv(&dir.path().join("tracks.csv"));
    let sigma_at = |sample: u64| {
        rows.iter()
            .find(|r| num(r, "tick") as u64 == sample * 10)
            .map(|r| num(r, "sigma_p_m"))
            .unwrap()
    };
    // Predicted without measurements from sample 40 on: the position's sigma grows, and
    // shrinks again once they come back.
    assert!(
        sigma_at(60) > 3.0 * sigma_at(39),
        "{} {}",
        sigma_at(60),
        sigma_at(39)
    );
    assert!(sigma_at(80) < sigma_at(60));
    assert!(s["faults"].to_string().contains("tracker"), "{s}");
}

#[test]
fn realtime_crossing_survives_a_kill_of_the_tracker_and_a_live_swap_of_it() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("crossing-swap.toml");
        let crossing = run(&["scenario", "crossing"]);
        let text = String::from_utf8_lossy(&crossing.stdout).to_string();
        std::fs::write(
        &file,
        text + "\n[[swap]]\ntime_s = 12.0\nrole = \"tracker\"\ncommand = [\"scmpc\", \"tracker\"]\n",
    )
    .unwrap();
        let run_dir = dir.path().join("run");
        common::kill_role_during_run(
            &run_dir,
            &[
                file.to_str().unwrap(),
                "--mode",
                "realtime",
                "--set",
                "duration_s=26",
            ],
            "tracker",
            5.0,
        );
        let s = summary(&run_dir);
        assert_eq!(s["outcome"], "reached", "{s}");
        assert_eq!(s["contacts_moving"], 0);
        let ev = events(&run_dir);
        machine.judge(&ev)?;
        assert!(
            common::has_event(&ev, "restarted", "tracker"),
            "no restart of the tracker"
        );
        assert!(
            ev.iter()
                .any(|e| e["event"] == "swapped" && e["role"] == "tracker"),
            "no swap of the tracker"
        );
        assert!(s["leftover_files"].as_array().unwrap().is_empty());
        Ok(())
    })
}

#[test]
fn a_robot_braked_where_a_person_walks_into_it_steps_out_of_the_way_only_with_evasion() {
    // Issue 56: the lidar fuzz's world 372 of seed 1. Every plan fails as the person
    // walks at the robot, which brakes to rest in their way; stepping out of it along its
    // heading (dfl.evasion), it is never touched.
    let _machine = common::machine_shared();
    let world = &fixture("fuzz-lidar-seed-1-world-372.toml");
    let dir = tempfile::tempdir().unwrap();
    let run = |evasion: bool| {
        let out = dir.path().join(format!("evasion-{evasion}"));
        let set = format!("dfl.evasion={evasion}");
        run_into(&out, &[world, "--in-process", "--set", &set])
    };
    let staying = run(false);
    assert_eq!(
        (
            &staying["contacts_at_rest"],
            &staying["commands"]["evasion"]
        ),
        (&1.into(), &0.into()),
        "{staying}"
    );
    let evading = run(true);
    assert_eq!(
        (&evading["contacts_at_rest"], &evading["contacts_moving"]),
        (&0.into(), &0.into()),
        "{evading}"
    );
    assert!(
        evading["commands"]["evasion"].as_u64() > Some(0),
        "{evading}"
    );
    assert_eq!(evading["outcome"], "reached");
}
