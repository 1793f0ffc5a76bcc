//! The Python side: the message layouts of `python/scmpc` against `scmpc schema`, the
//! Python estimator of `examples/python` swapped into a real-time run, and `run.mcap` read
//! back by the `mcap` package (with the example role of `examples/roles` recorded in it, and
//! the plans laid over each other by `examples/python/plan_departure.py`).
//!
//! These tests make their own venv under the target directory ([`common::python`]).

use crate::common;

use common::python::{python, read_mcap, repo, run_python};
use common::{events, run, stderr};
use record::schema::Table;

#[test]
fn the_python_message_layouts_are_the_ones_scmpc_schema_prints() {
    let _machine = common::machine_shared();
    let schema = run(&["schema"]);
    assert_eq!(schema.status.code(), Some(0), "{}", stderr(&schema));
    let out = run_python(&repo().join("tests/python/layouts.py"), &[], &schema.stdout);
    let schema: serde_json::Value = serde_json::from_slice(&schema.stdout).unwrap();
    let counted = |key: &str| schema[key].as_array().map_or(0, Vec::len);
    let compared = format!(
        "{} types, {} services compared",
        counted("types"),
        counted("services")
    );
    assert!(out.contains(&compared), "{out}");
}

#[test]
fn a_python_ekf_swapped_in_at_8_s_filters_the_noise_and_misses_no_deadline_and_no_tick() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let estimator = repo().join("examples/python/estimator.py");
        let file = dir.path().join("scenario.toml");
        // The noise of the paper's noisy study (Fig. 4(d)): a passthrough would be off by the
        // noise's sigma, an EKF by a small part of it.
        let noise_variance = 0.05;
        // The robot, quicker with the input weighed less, is at its goal by about 8 s (the
        // paper's weights take 24 s with this noise); the run goes on to its end, the Python
        // estimator filtering from the switch on.
        let duration_s = 16.0;
        std::fs::write(
        &file,
        format!(
            "name = \"python-estimator\"\nduration_s = {duration_s:?}\n\n[robot]\nfinal_approach = \
             \"paper\"\n\n[mpc]\nr_diag = [3.0, 3.0]\n\n[plant]\nnoise_variance = \
             {noise_variance}\n\n[[swap]]\ntime_s = 8.0\nrole = \"estimator\"\ncommand = \
             [{:?}, {:?}]\n",
            python(),
            estimator
        ),
    )
    .unwrap();
        let (out_dir, s, ev) = common::run_realtime(dir.path(), file.to_str().unwrap());
        assert_eq!(s["outcome"], "reached", "{s:#}");
        // Every tick was commanded from a finite estimate, but those lost in a stall of the
        // machine (a CI run at ca71f2d had 12 record gaps, a run on the development machine 8).
        let trajectory = Table::read(&out_dir.join("trajectory.csv")).unwrap();
        let mut faults = common::stalls::faults(&ev);
        let x_hat = trajectory.numbers("x_hat").unwrap();
        for (t, _) in
            (trajectory.numbers("t").unwrap().iter().zip(&x_hat)).filter(|(_, x)| !x.is_finite())
        {
            let tick = (t / 0.005).round() as u64;
            faults.push(common::stalls::Fault::at(
                "tick without an estimate",
                tick,
                String::new(),
            ));
        }
        machine.judge_faults(&ev, &faults)?;
        assert_eq!(s["swaps"], 1);
        assert!(
            s["rejected_samples"].as_object().unwrap().is_empty(),
            "{}",
            s["rejected_samples"]
        );
        let swapped = ev
            .iter()
            .find(|e| e["event"] == "swapped" && e["role"] == "estimator")
            .unwrap_or_else(|| panic!("no swap in {ev:#?}"));
        let switch_tick = swapped["switch_tick"].as_u64().unwrap();
        assert_eq!(switch_tick % 10, 0, "switch at tick {switch_tick}");
        let switch_s = switch_tick as f64 * 0.005;
        // Started at 8 s; switched within a second of reporting ready. How long Python takes to
        // start is its own: 0.15-0.2 s warm, 1.3-2 s for the first run after minutes idle on
        // the development machine (2026-11-28).
        let at = |event: &str| {
            ev.iter()
                .find(|e| e["event"] == event && e["role"] == "estimator")
                .and_then(|e| e["t"].as_f64())
                .unwrap_or_else(|| panic!("no {event} of the estimator"))
        };
        // An event's `t` is the newest tick recorded when it happened, which may be one inner
        // tick (5 ms) behind the clock that started the swap at 8 s (a CI run at 5bba432 had
        // 7.995 s).
        assert!((7.995 - 1e-9..8.1).contains(&at("swap_started")), "{ev:#?}");
        let ready_s = at("ready");
        assert!(
            switch_s > ready_s && switch_s < ready_s + 1.0,
            "switch at {switch_s} s, ready at {ready_s} s"
        );
        let python_epoch = swapped["to_epoch"].as_u64().unwrap();
        assert!(python_epoch > 0);
        let gaps = s["record_gaps"].as_u64().unwrap() as usize;
        assert_eq!(trajectory.len(), (duration_s / 0.005) as usize - gaps);
        // The Python estimator filters as the Rust one does: its position error against the
        // truth, per axis (RMS), is a small part of the noise's sigma (measured on 2026-11-25:
        // 0.010 m after the switch against 0.012 m for the Rust EKF before it, sigma 0.22 m).
        let column = |name| trajectory.numbers(name).unwrap();
        let (t, x, y) = (column("t"), column("x"), column("y"));
        let (x_hat, y_hat) = (column("x_hat"), column("y_hat"));
        let rms_error = |from_s: f64, to_s: f64| {
            let rows: Vec<usize> = (0..t.len())
                .filter(|&i| (from_s..to_s).contains(&t[i]) && x_hat[i].is_finite())
                .collect();
            let sum: f64 = rows
                .iter()
                .map(|&i| (x_hat[i] - x[i]).powi(2) + (y_hat[i] - y[i]).powi(2))
                .sum();
            (sum / (2.0 * rows.len() as f64)).sqrt()
        };
        // From 1 s in (the initial variance spent) to the switch, and from 1 s after it.
        let (rust_m, python_m) = (
            rms_error(1.0, switch_s),
            rms_error(switch_s + 1.0, duration_s),
        );
        let sigma = f64::sqrt(noise_variance);
        assert!(
            python_m < 0.25 * sigma && python_m < 2.0 * rust_m,
            "Python estimate off by {python_m} m RMS, the Rust EKF by {rust_m} m, sigma {sigma} m"
        );
        // The estimates recorded: the Rust estimator's before the switch, the Python one's
        // from it on.
        let mcap = read_mcap(&out_dir, false);
        let estimates = &mcap["/estimator/estimate"];
        let ticks = estimates["ticks"].as_array().unwrap();
        let epochs = estimates["epochs"].as_array().unwrap();
        assert_eq!(ticks.len(), trajectory.len());
        for (tick, epoch) in ticks.iter().zip(epochs) {
            let expected = if tick.as_u64().unwrap() < switch_tick {
                0
            } else {
                python_epoch
            };
            assert_eq!(epoch.as_u64(), Some(expected), "estimate of tick {tick}");
        }
        Ok(())
    })
}

#[test]
fn run_mcap_shows_the_moving_obstacles_every_tick_and_the_tracks_with_their_predicted_discs() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&["run", "crossing", "--out", out_dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let topics = read_mcap(&out_dir, false);
    let count = |topic: &str| topics[topic]["count"].as_u64().unwrap_or(0) as usize;
    let ticks = Table::read(&out_dir.join("trajectory.csv")).unwrap().len();
    assert_eq!(count("/world/moving_obstacles"), ticks);
    // The person crossing moves; the one standing is in the world at rest.
    assert_eq!(
        topics["/world/moving_obstacles"]["entities"]["obstacles_moving"],
        1
    );
    assert_eq!(topics["/world/obstacles"]["entities"]["obstacles"], 1);
    let tracks = Table::read(&out_dir.join("tracks.csv")).unwrap().len();
    assert_eq!(count("/tracker/tracks"), tracks);
    let entities = &topics["/tracker/tracks"]["entities"];
    assert_eq!(entities["tracks"], 1);
    assert_eq!(entities["predicted"], 8, "a disc per stage of N = 8");
    assert_eq!(topics["/tracker/tracks"]["schema"], "foxglove.SceneUpdate");
}

#[test]
fn every_scan_is_in_run_mcap_from_where_the_lidar_was_and_in_scan_csv_and_path_png_shows_some() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&["run", "unmapped", "--out", out_dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let topics = read_mcap(&out_dir, false);
    let scans = &topics["/lidar/laser_scan"];
    assert_eq!(scans["schema"], "foxglove.LaserScan");
    assert_eq!(scans["schema_errors"], serde_json::json!([]));
    let table = Table::read(&out_dir.join("scan.csv")).unwrap();
    assert_eq!(scans["count"].as_u64(), Some(table.len() as u64));
    let column = |name: &str| -> Vec<f64> {
        (table.column(name).unwrap().iter())
            .map(|v| v.parse().unwrap())
            .collect()
    };
    let numbers = |key: &str| -> Vec<f64> {
        (scans[key].as_array().unwrap().iter())
            .map(|v| v.as_f64().unwrap())
            .collect()
    };
    assert!(numbers("beams").iter().all(|&b| b == 360.0));
    assert_eq!(numbers("returns"), column("returns"));
    assert!(
        column("returns").iter().all(|&r| r > 0.0),
        "the box is always in sight"
    );
    // The first scan is taken where the robot starts, the lidar at its centre.
    assert_eq!(scans["origins"][0], serde_json::json!([-4.0, 0.0]));
    // The path figure shows what the lidar saw every 2 s, as dots.
    let path = std::fs::read_to_string(out_dir.join("path.svg")).unwrap();
    assert!(
        path.contains("lidar returns, every 2 s"),
        "path.svg has no returns"
    );
    assert!(
        path.matches("<circle").count() > 100,
        "path.svg has too few dots"
    );
}

#[test]
fn run_mcap_holds_every_tick_plan_verdict_route_and_event_of_the_run() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&["run", "field", "--out", out_dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let topics = read_mcap(&out_dir, false);
    let count = |topic: &str| topics[topic]["count"].as_u64().unwrap_or(0) as usize;

    let ticks = Table::read(&out_dir.join("trajectory.csv")).unwrap().len();
    for topic in [
        "/robot/truth",
        "/robot/estimate",
        "/estimator/estimate",
        "/dfl/command",
        "/robot/clearance",
        "/pipeline/latency",
    ] {
        assert_eq!(count(topic), ticks, "{topic}");
    }
    assert_eq!(count("/robot/covariance"), ticks.div_ceil(10));
    let plans = Table::read(&out_dir.join("plans.csv")).unwrap();
    assert_eq!(count("/mpc/plan"), plans.len());
    let horizons = plans.numbers("horizon").unwrap();
    let poses = topics["/mpc/plan"]["poses"].as_array().unwrap();
    for (poses, horizon) in poses.iter().zip(&horizons) {
        assert_eq!(poses.as_f64(), Some(horizon + 1.0));
    }
    let judged = plans
        .column("deadline_met")
        .unwrap()
        .iter()
        .filter(|m| !m.is_empty())
        .count();
    assert_eq!(count("/dfl/deadline"), judged);
    let routes = Table::read(&out_dir.join("route.csv")).unwrap();
    let mut route_plans = routes.numbers("plan").unwrap();
    route_plans.dedup();
    assert_eq!(count("/planner/route"), route_plans.len());
    assert_eq!(count("/events"), events(&out_dir).len());
    // The typed events: each line of events.jsonl as it is, valid under the channel's
    // schema (record::EventLine) by a validator we did not write.
    assert_eq!(
        topics["/run/events"]["events"].as_array(),
        Some(&events(&out_dir))
    );
    assert_eq!(
        topics["/run/events"]["schema_errors"],
        serde_json::json!([])
    );
    assert_eq!(count("/world/obstacles"), 1);
    let obstacles = std::fs::read_to_string(out_dir.join("scenario.toml"))
        .unwrap()
        .matches("[[obstacles]]")
        .count();
    let world = &topics["/world/obstacles"]["entities"];
    assert_eq!(world["obstacles"], obstacles);
    assert_eq!(world["obstacles_inflated"], obstacles);
    assert_eq!(world["start_goal"], 2);

    // Foxglove's own schemas where it has one, all JSON, on the run's simulated clock.
    for (topic, schema) in [
        ("/robot/truth", "foxglove.PoseInFrame"),
        ("/mpc/plan", "foxglove.PosesInFrame"),
        ("/world/obstacles", "foxglove.SceneUpdate"),
        ("/events", "foxglove.Log"),
        ("/run/events", "scmpc.Event"),
        ("/dfl/command", "scmpc.Command"),
    ] {
        let t = &topics[topic];
        assert_eq!(t["schema"], schema, "{topic}");
        assert_eq!(t["schema_encoding"], "jsonschema");
        assert_eq!(t["message_encoding"], "json");
        assert_eq!(t["schema_is_json"], true);
    }
    let times = topics["/robot/truth"]["log_time_ns"].as_array().unwrap();
    let t = Table::read(&out_dir.join("trajectory.csv"))
        .unwrap()
        .numbers("t")
        .unwrap();
    for (ns, t) in times.iter().zip(&t).step_by(997) {
        assert!(
            (ns.as_f64().unwrap() * 1e-9 - t).abs() < 1e-4,
            "{ns} ns, t = {t}"
        );
    }

    let no_mcap = dir.path().join("no-mcap");
    let out = run(&[
        "run",
        "--set",
        "duration_s=1",
        "--no-mcap",
        "--out",
        no_mcap.to_str().unwrap(),
    ]);
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    assert!(no_mcap.join("trajectory.csv").exists());
    assert!(!no_mcap.join("run.mcap").exists());
}

#[test]
fn the_example_role_runs_alike_in_process_and_in_lockstep_and_its_samples_are_in_csv_and_run_mcap()
{
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let mut files = Vec::new();
    for (name, executor) in [("in_process", Some("--in-process")), ("lockstep", None)] {
        let out_dir = dir.path().join(name);
        let mut args = vec!["run", "--set", r#"extra_roles=["odometer"]"#, "--out"];
        args.push(out_dir.to_str().unwrap());
        args.extend(executor);
        let out = run(&args);
        assert_eq!(out.status.code(), Some(0), "{name}: {}", stderr(&out));

        // A row per MPC sample: the length of the path the estimate drove up to it.
        let odometry = Table::read(&out_dir.join("odometry.csv")).unwrap();
        let (ticks, distances) = (
            odometry.numbers("tick").unwrap(),
            odometry.numbers("distance_m").unwrap(),
        );
        let trajectory = Table::read(&out_dir.join("trajectory.csv")).unwrap();
        let x = trajectory.numbers("x_hat").unwrap();
        let y = trajectory.numbers("y_hat").unwrap();
        assert_eq!(distances.len(), x.len().div_ceil(10), "{name}");
        for (tick, distance) in ticks.iter().zip(&distances) {
            let j = *tick as usize;
            let path: f64 = (1..=j)
                .map(|i| (x[i] - x[i - 1]).hypot(y[i] - y[i - 1]))
                .sum();
            assert!(
                (distance - path).abs() < 1e-9,
                "{name}: tick {tick}: {distance} m, path {path} m"
            );
        }
        assert!(distances.last().unwrap() > &5.0, "{name}: the robot drove");

        // The same samples on run.mcap's channel, each valid under its schema, read by a
        // reader we did not write.
        let topics = read_mcap(&out_dir, false);
        let channel = &topics["/odometer/odometry"];
        assert_eq!(channel["schema"], "scmpc.Odometry", "{name}");
        assert_eq!(
            channel["schema_errors"].as_array().map(Vec::len),
            Some(0),
            "{name}"
        );
        let logged: Vec<f64> = (channel["messages"].as_array().unwrap().iter())
            .map(|m| m["distance_m"].as_f64().unwrap())
            .collect();
        assert_eq!(logged, distances, "{name}");
        files.push(std::fs::read(out_dir.join("odometry.csv")).unwrap());
    }
    assert!(
        files[0] == files[1],
        "lockstep's odometry.csv differs from in process"
    );
}

/// `swap4` for 3 s in process into `dir/run` (its robots still on their way: exit 1).
fn swap4_for_3_s(dir: &std::path::Path) -> std::path::PathBuf {
    let out_dir = dir.join("run");
    let out = run(&[
        "run",
        "swap4",
        "--in-process",
        "--set",
        "duration_s=3",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    out_dir
}

/// A fleet's `run.mcap` is one file, read by the `mcap` package: every robot's channels
/// under its id, as many truths as its `trajectory.csv` has ticks, and the messages of
/// all robots in log-time order in the file itself (read in file order), as a viewer
/// plays them. No robot keeps a file of its own.
#[test]
fn a_fleets_run_mcap_has_every_robots_channels_under_its_id_in_log_time_order() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = swap4_for_3_s(dir.path());
    let topics = read_mcap(&out_dir, true);
    let mut read_order = Vec::new();
    for id in 0..4 {
        let robot = out_dir.join(format!("robot{id}"));
        assert!(!robot.join("run.mcap").exists());
        let ticks = Table::read(&robot.join("trajectory.csv")).unwrap().len();
        let truth = &topics[format!("/robot{id}/robot/truth")];
        assert_eq!(truth["count"].as_u64(), Some(ticks as u64), "robot {id}");
        assert!(topics[format!("/robot{id}/mpc/plan")]["count"].as_u64() > Some(0));
        let times = truth["log_time_ns"].as_array().unwrap().iter();
        let positions = truth["positions"].as_array().unwrap().iter();
        read_order.extend(positions.map(|p| p.as_u64()).zip(times.map(|t| t.as_u64())));
    }
    read_order.sort();
    assert!(
        read_order.windows(2).all(|w| w[0].1 <= w[1].1),
        "a truth read before an earlier one"
    );
}

/// `examples/python/plan_departure.py` reads every robot's plans of a fleet's `run.mcap`
/// and lays each over the one before it: every robot's plans come a sample apart, and
/// each new plan starts within a centimetre of where the last one put the robot (the DFL
/// flies the plan, the estimate is close to the truth). A brake begun along a plan ends
/// within `(a + b) T^2 / 2` of the plan's last stage `T = N Ts` after its time (the plan
/// accelerates within `a = sqrt(2) mpc.v_max`, the brake at `b = dfl.brake_decel`; the
/// script's velocities, from the stages' differences, are off by less than `a Ts / 2`,
/// far inside the bound's slack here). A later plan lies within `a T^2` of it there (it
/// and the plans flown since, from where the plan put the robot, all accelerate within
/// the box), and a centimetre for the estimate. And since `swap4`'s robots drive from the
/// start, a brake ends more than a centimetre off most plans (an observation of this run,
/// not a bound: it fails if the brakes are not laid along the plan).
#[test]
fn the_plan_departure_example_lays_each_plan_over_the_last_and_bounds_a_brake_begun_along_it() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = swap4_for_3_s(dir.path());
    let script = repo().join("examples/python/plan_departure.py");
    let json = std::path::Path::new("--json");
    let printed = run_python(&script, &[&out_dir, json], b"");
    let report: serde_json::Value = serde_json::from_str(&printed).unwrap();
    let topics = read_mcap(&out_dir, false);
    for id in 0..4 {
        let robot = &report[format!("robot{id}")];
        let plans = topics[format!("/robot{id}/mpc/plan")]["count"].as_u64();
        assert_eq!(robot["plans"].as_u64(), plans, "robot {id}: {robot}");
        assert_eq!(robot["pairs"].as_u64(), plans.map(|n| n - 1), "{robot}");
        let apart = robot["samples_apart"].as_object().unwrap();
        assert_eq!(apart.keys().collect::<Vec<_>>(), ["1"], "{robot}");
        let first_stage_max = robot["first_stage_m"][3].as_f64().unwrap();
        assert!((0.0..0.01).contains(&first_stage_max), "{robot}");
        let farthest = robot["farthest_stage_m"][3].as_f64().unwrap();
        assert!(farthest >= first_stage_max, "{robot}");
        // swap4: v_max 1 m/s, brake "auto" (1 m/s^2), N Ts = 0.4 s.
        let bound_m = (std::f64::consts::SQRT_2 + 1.0) * 0.4 * 0.4 / 2.0;
        let brake_reach = |q: usize| robot["brake_reach_m"][q].as_f64().unwrap();
        assert!(
            brake_reach(0) > 0.01 && brake_reach(3) <= bound_m,
            "{robot}"
        );
        let chained_max = robot["chained_last_stage_m"][3].as_f64().unwrap();
        let chain_bound_m = std::f64::consts::SQRT_2 * 0.4 * 0.4 + 0.01;
        assert!((0.0..chain_bound_m).contains(&chained_max), "{robot}");
    }
}
