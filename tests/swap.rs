//! Swap-in replacement, make-before-break: scheduled in the scenario (`[[swap]]`) or live
//! with `scmpc swap`, in real time and in lockstep.

use crate::common;

use common::{events, run, run_realtime, scmpc, spawn_run, summary, wait_for};
use record::schema::Table;
use std::path::Path;
use std::time::Duration;

/// Writes a scenario of the paper with `extra` appended (and the paper's arrival: the
/// swaps go on until `duration_s`); returns its path.
fn scenario_file(dir: &Path, extra: &str) -> String {
    let file = dir.join("scenario.toml");
    let paper_arrival = "[robot]\nfinal_approach = \"paper\"\n";
    std::fs::write(&file, format!("name = \"swaps\"\n{extra}\n{paper_arrival}")).unwrap();
    file.to_str().unwrap().to_string()
}

/// The `swapped` event of `role`.
fn swapped(ev: &[serde_json::Value], role: &str) -> serde_json::Value {
    ev.iter()
        .find(|e| e["event"] == "swapped" && e["role"] == role)
        .unwrap_or_else(|| panic!("no swap of the {role} in {ev:#?}"))
        .clone()
}

/// Every tick recorded in `trajectory.csv` (`ticks` of them) has a finite command and
/// estimate.
fn assert_every_tick_commanded(dir: &Path, ticks: usize) {
    let table = Table::read(&dir.join("trajectory.csv")).unwrap();
    assert_eq!(table.len(), ticks, "ticks recorded");
    let t = table.numbers("t").unwrap();
    for column in [
        "x_hat",
        "y_hat",
        "theta_hat",
        "zeta_hat",
        "v1",
        "v2",
        "u1",
        "u2",
    ] {
        for (i, value) in table.numbers(column).unwrap().into_iter().enumerate() {
            assert!(value.is_finite(), "t = {}: {column} is {value}", t[i]);
        }
    }
}

/// The swaps' claim: no deadline missed and no tick lost, the swaps' starts and switches
/// included, but in a stall of the machine itself (a stall of a shared CI VM, issue 47's
/// subject), as in the project's other real-time tests. A swap that lost a tick of its own
/// fails the judge unless a stall of the machine happens to cover that very tick. (The
/// swaps' windows were held to no gap at all until a fresh-clone CI run of ed511c6 lost
/// ticks 1721-1722 (8.6 s), in the second after the estimator's switch, inside a stall: it
/// saw 133 on the run's CPUs.)
#[test]
fn realtime_swaps_of_the_estimator_at_8_s_and_the_mpc_at_12_s_cost_no_deadline_and_no_tick() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let file = scenario_file(
            dir.path(),
            r#"duration_s = 14.0

[[swap]]
time_s = 8.0
role = "estimator"
command = ["scmpc", "estimator", "--set", "estimator.kind=passthrough"]

[[swap]]
time_s = 12.0
role = "mpc"
command = ["scmpc", "mpc", "--set", "mpc.horizon=10"]
"#,
        );
        let (out_dir, s, ev) = run_realtime(dir.path(), &file);
        machine.judge(&ev)?;
        let gaps = s["record_gaps"].as_u64().unwrap() as usize;
        assert_eq!(s["swaps"], 2);
        assert!(
            s["rejected_samples"].as_object().unwrap().is_empty(),
            "{}",
            s["rejected_samples"]
        );
        assert_every_tick_commanded(&out_dir, 2800 - gaps);
        for (role, at_s) in [("estimator", 8.0), ("mpc", 12.0)] {
            let e = swapped(&ev, role);
            let tick = e["switch_tick"].as_u64().unwrap();
            assert_eq!(
                tick % 10,
                0,
                "{role}: switch at tick {tick}, not a sample boundary"
            );
            let t = tick as f64 * 0.005;
            assert!(t > at_s && t < at_s + 1.0, "{role}: switch at t = {t}");
            assert_ne!(e["old_pid"], e["new_pid"]);
            let old = e["from_epoch"].as_u64().unwrap();
            assert!(
                ev.iter()
                    .any(|r| r["event"] == "retired" && r["role"] == role && r["epoch"] == old),
                "the old {role} was not stopped"
            );
        }
        // The replacement MPC runs its own options: plans of horizon 10 from its switch on.
        let mpc_switch = swapped(&ev, "mpc")["switch_tick"].as_u64().unwrap() / 10;
        let plans = Table::read(&out_dir.join("plans.csv")).unwrap();
        // One row per sample, none twice, none missing; the plan of the last sample (280, at
        // the run's final tick) may or may not arrive before a real-time run ends. A plan
        // whose verdict the orchestrator never got (a stall of the machine, as a record gap)
        // has its row written at the end of the run: rows are compared in sample order (a CI
        // run at 041c9ed wrote plan 86's row after plan 278's).
        let mut rows: Vec<(u64, &str)> = plans
            .numbers("sample")
            .unwrap()
            .into_iter()
            .map(|s| s as u64)
            .zip(plans.column("horizon").unwrap())
            .collect();
        rows.sort_by_key(|&(sample, _)| sample);
        assert!(rows.len() >= 280, "{} plan rows", rows.len());
        assert!(
            rows.iter().enumerate().all(|(i, (s, _))| *s == i as u64),
            "{rows:?}"
        );
        for (sample, horizon) in rows {
            let expected = if sample < mpc_switch { "8" } else { "10" };
            assert_eq!(horizon, expected, "plan {sample}");
        }
        assert!(s["leftover_files"].as_array().unwrap().is_empty());
        Ok(())
    })
}

#[test]
fn scmpc_swap_replaces_the_dfl_of_a_running_run_and_refuses_what_it_cannot_do() {
    // Alone, so that the swap is not slowed past its timeout; the claim is the swap, not
    // the run's timing (the test above judges that).
    let _machine = common::machine_alone();
    let dir = tempfile::tempdir().unwrap();
    let run_dir = dir.path().join("run");
    let mut child = spawn_run(&run_dir, &["--mode", "realtime", "--set", "duration_s=5"]);
    assert!(
        wait_for(Duration::from_secs(10), || events(&run_dir)
            .iter()
            .any(|e| e["event"] == "ready")),
        "the run never became ready"
    );
    let dir_arg = run_dir.to_str().unwrap();
    let plant = run(&["swap", "--run", dir_arg, "plant"]);
    assert_eq!(plant.status.code(), Some(2), "{}", common::stderr(&plant));
    assert!(common::stderr(&plant).contains("plant"));

    let out = run(&["swap", "--run", dir_arg, "dfl"]);
    assert_eq!(out.status.code(), Some(0), "{}", common::stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("swapped dfl"));
    let missing = run(&[
        "swap",
        "--run",
        dir_arg,
        "mpc",
        "--",
        "/nonexistent/program",
    ]);
    assert_eq!(missing.status.code(), Some(1));
    assert!(common::stderr(&missing).contains("/nonexistent/program"));

    child.wait().unwrap();
    let s = summary(&run_dir);
    let ev = events(&run_dir);
    swapped(&ev, "dfl");
    assert!(ev.iter().any(
        |e| e["event"] == "swap_refused" && e["reason"].as_str().unwrap().contains("not found")
    ));
    assert_eq!(s["swaps"], 1);
    let ended = run(&["swap", "--run", dir_arg, "dfl"]);
    assert_eq!(ended.status.code(), Some(2));
    assert!(
        common::stderr(&ended).contains("ended"),
        "{}",
        common::stderr(&ended)
    );
}

#[test]
fn a_lockstep_swap_of_every_swappable_role_keeps_the_run_whole() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let file = scenario_file(
        dir.path(),
        r#"
extra_roles = ["odometer"]

[[swap]]
time_s = 3.0
role = "dfl"

[[swap]]
time_s = 5.0
role = "estimator"

[[swap]]
time_s = 7.0
role = "mpc"

[[swap]]
time_s = 9.0
role = "odometer"
"#,
    );
    let out_dir = dir.path().join("run");
    let out = run(&["run", &file, "--out", out_dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", common::stderr(&out));
    let s = summary(&out_dir);
    let ev = events(&out_dir);
    for role in ["dfl", "estimator", "mpc", "odometer"] {
        swapped(&ev, role);
    }
    assert_eq!(s["outcome"], "reached");
    assert_eq!(s["swaps"], 4);
    assert_eq!(s["deadline_misses"], 0);
    assert!(
        s["rejected_samples"].as_object().unwrap().is_empty(),
        "{}",
        s["rejected_samples"]
    );
    assert_every_tick_commanded(&out_dir, 6000);
    // The example role's reading of every sample once, though each swap has every process
    // publish its newest output again.
    let odometry = record::schema::Table::read(&out_dir.join("odometry.csv")).unwrap();
    let ticks = odometry.numbers("tick").unwrap();
    assert_eq!(ticks.len(), 600);
    assert!(
        ticks.windows(2).all(|w| w[0] < w[1]),
        "a tick recorded twice"
    );
    // Fresh processes of the same code continue the same trajectory closely.
    let t = s["time_to_goal_s"].as_f64().unwrap();
    assert!((t - 24.105).abs() < 0.2, "time to goal {t}");
}

#[test]
fn in_lockstep_a_replacement_slow_to_start_holds_the_clock_and_switches_before_the_end() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    // The replacement starts half a second after it is spawned; the last second of the
    // run takes a few ms in lockstep, so the clock must wait for the replacement to join.
    // (Gentler inputs' weight: the goal is reached at 7.5 s, before the swap.)
    let file = scenario_file(
        dir.path(),
        &format!(
            r#"duration_s = 10.0

[mpc]
r_diag = [3.0, 3.0]

[[swap]]
time_s = 9.0
role = "mpc"
command = ["sh", "-c", "sleep 0.5 && exec \"$0\" mpc --set mpc.horizon=10", "{}"]
"#,
            env!("CARGO_BIN_EXE_scmpc")
        ),
    );
    let out_dir = dir.path().join("run");
    let out = run(&["run", &file, "--out", out_dir.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", common::stderr(&out));
    let s = summary(&out_dir);
    assert_eq!(s["outcome"], "reached");
    assert_eq!(s["swaps"], 1, "{s}");
    let switch_tick = swapped(&events(&out_dir), "mpc")["switch_tick"]
        .as_f64()
        .unwrap();
    assert!(
        (1800.0..2000.0).contains(&switch_tick),
        "switch at tick {switch_tick}"
    );
    let plans = Table::read(&out_dir.join("plans.csv")).unwrap();
    let horizons = plans.numbers("horizon").unwrap();
    let epochs = plans.numbers("mpc_epoch").unwrap();
    assert!(
        epochs
            .iter()
            .zip(&horizons)
            .any(|(&e, &n)| e == 1.0 && n == 10.0),
        "no plan of the replacement"
    );
    assert_every_tick_commanded(&out_dir, 2000);
}

#[test]
fn a_swap_of_the_plant_or_of_a_missing_program_is_refused_before_the_run() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    for (extra, key) in [
        ("[[swap]]\ntime_s = 1.0\nrole = \"plant\"\n", "swap.0.role"),
        ("[[swap]]\ntime_s = 99.0\nrole = \"mpc\"\n", "swap.0.time_s"),
        (
            "[[swap]]\ntime_s = 1.0\nrole = \"mpc\"\ncommand = [\"no-such-program-x\"]\n",
            "swap.0.command",
        ),
    ] {
        let file = scenario_file(dir.path(), extra);
        let out_dir = dir.path().join("run");
        let out = scmpc()
            .args(["run", &file, "--out", out_dir.to_str().unwrap()])
            .output()
            .unwrap();
        let msg = common::stderr(&out);
        assert_eq!(out.status.code(), Some(2), "{extra}: {msg}");
        assert!(
            msg.contains(key),
            "{extra}: message does not name `{key}`: {msg}"
        );
        assert!(!out_dir.exists());
    }
}

#[test]
fn a_replacement_that_exits_or_publishes_nothing_within_the_swap_timeout_is_dropped_and_the_old_process_stays()
 {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let file = scenario_file(
            dir.path(),
            r#"duration_s = 5.5

[supervision]
swap_timeout_s = 3.0

[[swap]]
time_s = 1.0
role = "mpc"
command = ["sleep", "30"]

[[swap]]
time_s = 2.0
role = "estimator"
command = ["true"]
"#,
        );
        let (_, s, ev) = run_realtime(dir.path(), &file);
        let failed = |role: &str| {
            ev.iter()
                .find(|e| e["event"] == "swap_failed" && e["role"] == role)
                .unwrap_or_else(|| panic!("no failed swap of the {role} in {ev:#?}"))
                .clone()
        };
        let mpc = failed("mpc");
        assert!(
            mpc["reason"]
                .as_str()
                .unwrap()
                .contains("published nothing usable within 3s"),
            "{mpc}"
        );
        // Started at 1 s, given up 3 s later.
        assert!((mpc["t"].as_f64().unwrap() - 4.0).abs() < 0.5, "{mpc}");
        let estimator = failed("estimator");
        assert!(
            estimator["reason"].as_str().unwrap().contains("exited"),
            "{estimator}"
        );
        assert_eq!(s["swaps"], 0);
        assert_eq!(s["restarts"], 0);
        // The old processes went on undisturbed.
        machine.judge(&ev)?;
        assert!(s["leftover_files"].as_array().unwrap().is_empty());
        Ok(())
    })
}
