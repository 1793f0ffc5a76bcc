//! A base that follows its commands with a lag after a delay (issue 60,
//! `robot.actuator_lag_s`, `robot.command_delay_s`, docs/robot.md): the simulated plant
//! is such a base, the estimator and the DFL model it, and `summary.json` reports how far
//! the robot ends up from where each plan put it one sample on (`plan_following_mm`).

use crate::common;

use common::ros2::{Robot, base_inputs_kept, run_on};
use common::{run_into_tempdir, stderr, summary};

/// The lag and the delay of the base of these tests, s.
const LAG_S: f64 = 0.05;
const DELAY_S: f64 = 0.02;

/// The summary of `scenario` run in process with the final approach that settles and
/// `sets`.
fn run_with(scenario: &str, sets: &[String]) -> serde_json::Value {
    let mut args = vec![
        "run",
        scenario,
        "--in-process",
        "--set",
        "robot.final_approach=settle",
    ];
    for set in sets {
        args.extend(["--set", set.as_str()]);
    }
    let (dir, out) = run_into_tempdir(&args);
    assert!(
        out.status.success(),
        "{scenario} {sets:?}: {}",
        stderr(&out)
    );
    summary(dir.path())
}

fn base(section: &str) -> Vec<String> {
    vec![
        format!("{section}.actuator_lag_s={LAG_S}"),
        format!("{section}.command_delay_s={DELAY_S}"),
    ]
}

#[test]
fn a_lagged_delayed_base_that_is_modelled_arrives_settles_and_follows_its_plans_better() {
    let _machine = common::machine_shared();
    for scenario in ["paper", "field"] {
        let ideal = run_with(scenario, &[]);
        let modelled = run_with(scenario, &base("robot"));
        let told_zero = run_with(scenario, &base("plant"));
        let following =
            |s: &serde_json::Value, q: &str| s["plan_following_mm"][q].as_f64().unwrap();
        eprintln!(
            "{scenario}: plan following p50/p99 (mm): ideal base {:.4}/{:.4}, lagged base \
             modelled {:.3}/{:.3}, told zero {:.3}/{:.3}",
            following(&ideal, "p50"),
            following(&ideal, "p99"),
            following(&modelled, "p50"),
            following(&modelled, "p99"),
            following(&told_zero, "p50"),
            following(&told_zero, "p99"),
        );
        assert!(following(&ideal, "p99") < 0.01, "{scenario}: {ideal}");
        for q in ["p50", "p99"] {
            assert!(
                following(&told_zero, q) > 10.0 * following(&modelled, q),
                "{scenario}: a model of the lag and the delay should cut the \
                 plan-following error's {q} tenfold: modelled {modelled}, told zero {told_zero}"
            );
        }
        let arrival = &modelled["arrival"];
        assert_eq!(modelled["outcome"], "reached", "{scenario}: {modelled}");
        assert_eq!(modelled["contacts_moving"], 0, "{scenario}: {modelled}");
        assert_eq!(modelled["contacts_at_rest"], 0, "{scenario}: {modelled}");
        assert!(
            arrival["largest_distance_after_m"].as_f64().unwrap() <= 0.25,
            "{scenario}: {arrival}"
        );
        assert!(
            arrival["time_to_rest_s"].as_f64().is_some_and(|s| s <= 3.0),
            "{scenario}: {arrival}"
        );
    }
}

/// Random worlds (`scmpc fuzz`, people on the way in half of them) on the lagged, delayed
/// base that is modelled: none collides, and people walk into a robot at rest in few.
#[test]
fn in_random_worlds_a_lagged_delayed_base_that_is_modelled_never_collides() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("fuzz");
    let mut args = vec!["fuzz", "--count", "100", "--out", out_dir.to_str().unwrap()];
    let sets = base("robot");
    args.extend(sets.iter().flat_map(|s| ["--set", s.as_str()]));
    let out = common::run(&args);
    let rows = common::csv(&out_dir.join("fuzz.csv"));
    assert_eq!(rows.len(), 100, "{}", stderr(&out));
    let collided: Vec<&str> = (rows.iter())
        .filter(|r| r["outcome"] == "collided")
        .map(|r| r["world"].as_str())
        .collect();
    assert!(collided.is_empty(), "worlds {collided:?} collided");
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let at_rest = rows
        .iter()
        .filter(|r| common::num(r, "contacts_at_rest") > 0.0)
        .count();
    assert!(
        at_rest <= 3,
        "people walked into the robot at rest in {at_rest} worlds"
    );
}

/// The lag and the delay `scmpc identify` prints (`[robot]` keys) for `sets`, from the
/// origin.
fn identified(sets: &[String]) -> (f64, f64) {
    let mut args = vec!["identify", "--set", "robot.start=[0,0,0]"];
    for set in sets {
        args.extend(["--set", set.as_str()]);
    }
    let out = common::run(&args);
    assert!(out.status.success(), "{sets:?}: {}", stderr(&out));
    keys_printed(&out.stdout)
}

/// `robot.actuator_lag_s` and `robot.command_delay_s` of `scmpc identify`'s output.
fn keys_printed(stdout: &[u8]) -> (f64, f64) {
    let text = String::from_utf8_lossy(stdout).to_string();
    let keys: toml::Table = toml::from_str(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
    let key = |name: &str| keys["robot"][name].as_float().unwrap_or(f64::NAN);
    (key("actuator_lag_s"), key("command_delay_s"))
}

#[test]
fn identify_recovers_the_lag_and_the_delay_of_a_simulated_base_within_ten_percent() {
    let _machine = common::machine_shared();
    for (lag_s, delay_s) in [(0.05, 0.02), (0.1, 0.01), (0.02, 0.06), (0.15, 0.04)] {
        let (lag, delay) = identified(&[
            format!("plant.actuator_lag_s={lag_s}"),
            format!("plant.command_delay_s={delay_s}"),
            // Odometry with a millimetre's noise.
            "plant.noise_variance=1e-6".into(),
        ]);
        assert!(
            (lag / lag_s - 1.0).abs() <= 0.1 && (delay / delay_s - 1.0).abs() <= 0.1,
            "lag {lag_s} s, delay {delay_s} s: identified {lag} s and {delay} s"
        );
    }
}

#[test]
fn identify_refuses_to_start_near_an_obstacle_and_names_it() {
    let _machine = common::machine_shared();
    // The paper's obstacle is 0.3 m from a robot starting at (3, 1.7).
    let out = common::run(&["identify", "--set", "robot.start=[3,1.7,0]"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("obstacles.0"), "{}", stderr(&out));
    assert!(out.stdout.is_empty());
}

/// From the base's own truth (`[t_ns, x, y, ...]` rows) about the goal at the origin: the
/// largest distance after it first came within 0.2 m, and the time from then to its
/// final stay within 0.05 m, s.
fn arrival_of_truth(log: &serde_json::Value) -> (f64, Option<f64>) {
    let rows = log["truth"].as_array().expect("truth");
    let at = |row: &serde_json::Value, i: usize| row[i].as_f64().expect("a number");
    let path: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (at(r, 0) / 1e9, at(r, 1).hypot(at(r, 2))))
        .collect();
    let (_, farthest, to_rest) = common::arrival_of(&path, 0.05).expect("never within 0.2 m");
    (farthest, to_rest)
}

/// The test's ROS 2 base (a 50 ms lag, noisy odometry at 50 Hz, a watchdog): `scmpc
/// identify` measures its lag, and the paper scenario driven with what it measured
/// settles at its goal by the base's own truth.
#[test]
fn identify_measures_a_ros2_bases_lag_and_the_robot_driven_with_it_settles_at_its_goal() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let robot = Robot::start(dir.path(), &["--noise-std", "0.002", "--lag-s", "0.05"]);
        let ros2 = ["--set", "plant.kind=ros2", "--set"];
        let endpoint = format!("ros2.endpoint={}", robot.endpoint);
        let out = common::run(&[&["identify"][..], &ros2, &[endpoint.as_str()]].concat());
        assert!(out.status.success(), "{}", stderr(&out));
        let (lag, delay) = keys_printed(&out.stdout);
        eprintln!("{}", String::from_utf8_lossy(&out.stdout));
        assert!(
            (lag / 0.05 - 1.0).abs() <= 0.2,
            "lag {lag} s, delay {delay} s"
        );

        let out_dir = dir.path().join("run");
        let sets = [
            format!("robot.actuator_lag_s={lag}"),
            format!("robot.command_delay_s={delay}"),
            "robot.final_approach=settle".into(),
            "plant.noise_variance=4e-6".into(),
        ];
        let sets: Vec<&str> = sets.iter().flat_map(|s| ["--set", s.as_str()]).collect();
        let out = run_on(&robot.endpoint, &sets, &out_dir);
        let log = robot.finish();
        base_inputs_kept(machine, &out_dir)?;
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        assert_eq!(summary(&out_dir)["outcome"], "reached");
        let (farthest_m, to_rest_s) = arrival_of_truth(&log);
        eprintln!(
            "farthest after 0.2 m: {farthest_m:.3} m, to rest within 0.05 m: {to_rest_s:?} s"
        );
        assert!(farthest_m <= 0.25, "{farthest_m} m");
        assert!(to_rest_s.is_some_and(|s| s <= 3.0), "{to_rest_s:?}");
        Ok(())
    })
}
