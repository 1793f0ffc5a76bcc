//! Crashes: a dead process is detected, cleaned up, restarted or the run is aborted.

use crate::common;

use common::{
    events, kill_role_during_run, leftovers, scmpc, sigkill, spawn_run, summary, wait_for,
    wait_for_pid,
};
use record::schema::Table;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

#[test]
fn realtime_mpc_killed_at_5_s_is_restarted_and_the_robot_still_reaches_the_goal() {
    let _machine = common::machine_alone();
    let dir = tempfile::tempdir().unwrap();
    // Ending once the robot is held at its goal (`settle`), the input weighed less: about
    // 9 s, not the paper's 30 (the goal is reached at about 7.7 s, after the kill).
    let args = [
        "--mode",
        "realtime",
        "--set",
        "robot.final_approach=settle",
        "--set",
        "mpc.r_diag=[3,3]",
    ];
    kill_role_during_run(dir.path(), &args, "mpc", 5.0);
    let s = summary(dir.path());
    let ev = events(dir.path());
    assert!(
        ev.iter()
            .any(|e| e["event"] == "crashed" && e["role"] == "mpc"),
        "crash not recorded"
    );
    assert!(
        ev.iter()
            .any(|e| e["event"] == "restarted" && e["role"] == "mpc"),
        "mpc not restarted"
    );
    assert_eq!(s["outcome"], "reached");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
    // Plans resume within 0.5 s: at most 10 samples in a row without a plan (a restart
    // that beats the next deadline costs none).
    let streak = s["longest_miss_streak"].as_u64().unwrap();
    assert!(streak <= 10, "longest run of misses {streak}");
    let crash_t = ev.iter().find(|e| e["event"] == "crashed").unwrap()["t"]
        .as_f64()
        .unwrap();
    let plans = Table::read(&dir.path().join("plans.csv")).unwrap();
    let resumed = plans
        .numbers("t")
        .unwrap()
        .into_iter()
        .zip(plans.column("deadline_met").unwrap())
        .any(|(t, met)| t > crash_t && t <= crash_t + 0.5 && met == "true");
    assert!(
        resumed,
        "no on-time plan within 0.5 s of the crash at t = {crash_t}"
    );
    assert!(
        s["leftover_files"].as_array().unwrap().is_empty(),
        "{}",
        s["leftover_files"]
    );
}

#[test]
fn a_dead_plant_aborts_the_run_and_every_process_exits_cleanly() {
    let _machine = common::machine_alone();
    let dir = tempfile::tempdir().unwrap();
    let prefix = common::unique_prefix("plant");
    let mut child = spawn_run(
        dir.path(),
        &[
            "--mode",
            "realtime",
            "--set",
            "duration_s=10",
            "--prefix",
            &prefix,
        ],
    );
    let plant = wait_for_pid(dir.path(), "plant");
    common::SimulatedClock::of(&prefix).wait_until(0.5);
    sigkill(plant);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(1));
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "aborted");
    let events = common::events(dir.path());
    for role in ["estimator", "mpc", "dfl"] {
        let pid = s["pids"][role].as_u64().unwrap();
        assert!(
            !runtime::ipc::process_alive(pid as u32),
            "{role} still running"
        );
        // Stopped, not killed: each exited on its own, with status 0.
        let exited = events
            .iter()
            .find(|e| e["event"] == "exited" && e["role"] == role)
            .unwrap_or_else(|| panic!("no `exited` event for the {role}"));
        assert_eq!(exited["killed"], false, "{exited}");
        assert_eq!(exited["status"], "exit status: 0", "{exited}");
    }
    let prefix = s["iceoryx2_prefix"].as_str().unwrap();
    assert!(
        leftovers(prefix).is_empty(),
        "left behind: {:?}",
        leftovers(prefix)
    );
}

/// Every process of a run SIGKILLed at once (the orchestrator's process group, and the
/// roles, which run in groups of their own): nobody of the run is left to clean up.
#[test]
fn after_sigkill_of_every_process_of_a_run_a_new_run_starts_and_cleans_up() {
    let _machine = common::machine_alone();
    let dir = tempfile::tempdir().unwrap();
    let mut child = scmpc()
        .args([
            "run",
            "--mode",
            "realtime",
            "--out",
            dir.path().to_str().unwrap(),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .process_group(0)
        .spawn()
        .unwrap();
    let roles: Vec<u32> = ["plant", "estimator", "mpc", "dfl"]
        .iter()
        .map(|role| wait_for_pid(dir.path(), role))
        .collect();
    let prefix = events(dir.path())
        .iter()
        .find_map(|e| e["iceoryx2_prefix"].as_str().map(str::to_string))
        .unwrap();
    // SAFETY: killing the process group this test created, and the processes of its run.
    unsafe { libc::kill(-(child.id() as i32), libc::SIGKILL) };
    for pid in roles {
        sigkill(pid);
    }
    child.wait().unwrap();
    assert!(
        !leftovers(&prefix).is_empty(),
        "SIGKILL should have left files to clean"
    );
    let next = tempfile::tempdir().unwrap();
    let out = common::run(&[
        "run",
        "--set",
        "duration_s=2",
        "--out",
        next.path().to_str().unwrap(),
    ]);
    assert!(
        next.path().join("summary.json").exists(),
        "{}",
        common::stderr(&out)
    );
    assert_eq!(summary(next.path())["ticks"], 400);
    assert!(
        wait_for(Duration::from_secs(1), || leftovers(&prefix).is_empty()),
        "the dead run's files were not removed: {:?}",
        leftovers(&prefix)
    );
}

#[test]
fn while_the_estimator_is_down_the_dfl_brakes_on_its_own_clock() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        kill_role_during_run(
            dir.path(),
            &["--mode", "realtime", "--set", "duration_s=6"],
            "estimator",
            3.0,
        );
        let ev = events(dir.path());
        assert!(
            ev.iter()
                .any(|e| e["event"] == "restarted" && e["role"] == "estimator")
        );
        let crash_t = ev.iter().find(|e| e["event"] == "crashed").unwrap()["t"]
            .as_f64()
            .unwrap();
        let table = Table::read(&dir.path().join("trajectory.csv")).unwrap();
        let (t, zeta, u2) = (
            table.numbers("t").unwrap(),
            table.numbers("zeta").unwrap(),
            table.numbers("u2").unwrap(),
        );
        let braking: Vec<(f64, f64, f64)> = (table.column("mode").unwrap().iter())
            .enumerate()
            .filter(|(_, mode)| **mode == "brake")
            .map(|(i, _)| (t[i], zeta[i], u2[i]))
            .collect();
        // Braking outside the estimator's downtime (from 0.1 s before its crash to 0.5 s
        // after) falls in a stall of the machine, which silenced the estimator too: a brake
        // from silence comes in the third silent tick.
        let (down, elsewhere): (Vec<&(f64, f64, f64)>, Vec<_>) =
            (braking.iter()).partition(|b| b.0 >= crash_t - 0.1 && b.0 <= crash_t + 0.5);
        assert!(!down.is_empty(), "no braking while the estimator was down");
        let faults: Vec<common::stalls::Fault> = (elsewhere.iter())
            .map(|b| common::stalls::Fault {
                what: "brake",
                tick: ((b.0 / 0.005).round() as u64).saturating_sub(3),
                ticks: 4,
                detail: format!("{b:?}"),
            })
            .collect();
        machine.judge_faults(&ev, &faults)?;
        assert!(braking.iter().all(|b| b.2 == 0.0), "steering while braking");
        assert!(
            down.windows(2).all(|w| w[1].1.abs() <= w[0].1.abs()),
            "zeta grew while braking"
        );
        assert_eq!(
            summary(dir.path())["outcome"],
            "timeout",
            "the run did not go on to its end"
        );
        Ok(())
    })
}

#[test]
fn in_lockstep_killed_processes_are_restarted_and_the_loop_resumes_where_it_stopped() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let prefix = common::unique_prefix("restart");
    // Two simulated minutes (a few seconds of wall time): the kills at 5, 10 and 15 s come
    // long before the end, however slowly this test is scheduled.
    let args = ["--set", "duration_s=120", "--prefix", &prefix];
    let mut child = spawn_run(dir.path(), &args);
    let pids: Vec<(&str, u32)> = ["mpc", "dfl", "estimator"]
        .into_iter()
        .map(|role| (role, wait_for_pid(dir.path(), role)))
        .collect();
    let mut clock = common::SimulatedClock::of(&prefix);
    // Each role is killed at a simulated time of its own, once the one before is back.
    for ((role, pid), at_s) in pids.into_iter().zip([5.0, 10.0, 15.0]) {
        clock.wait_until(at_s);
        assert!(
            common::is_role_process(pid, role, &prefix),
            "pid {pid} is no longer the {role}"
        );
        sigkill(pid);
        assert!(
            wait_for(Duration::from_secs(5), || events(dir.path())
                .iter()
                .any(|e| e["event"] == "ready" && e["role"] == role)),
            "the {role} was not restarted: {:#?}",
            events(dir.path())
        );
    }
    drop(clock);
    assert_eq!(child.wait().unwrap().code(), Some(0));
    let s = summary(dir.path());
    assert_eq!(s["restarts"], 3);
    assert_eq!(s["outcome"], "reached");
    assert_eq!(s["ticks"], 24000);
    // Restarted processes pick up the loop's state: the robot goes as it goes without
    // crashes (a restarted estimator starts its covariance afresh, so not to the bit).
    let calm = tempfile::tempdir().unwrap();
    let out = common::run(&[
        "run",
        "--set",
        "duration_s=120",
        "--out",
        calm.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0));
    let calm_t = summary(calm.path())["time_to_goal_s"].as_f64().unwrap();
    // The MPC restarted solves its first plan cold (it has no plan of its own to start
    // from), which differs from the warm one by millimetres, and how much that moves the
    // arrival depends on the sample the kill lands at: 0.065, 0.175, 0.22 and 0.38 s in
    // four runs beside a fleet's runs on 2026-12-04 (the MPC killed at 5.185, 5.695 s...;
    // below 0.05 s in seven), when the sample-start wake-ups had made the lockstep run
    // faster than the test's look at the clock; 0.57 s in a fresh-clone CI rehearsal of
    // ed91dde (2026-12-04), whose paper run is byte for byte its parent's. A run that
    // did not resume would be seconds off, or not arrive; the path below is the finer
    // check.
    let t = s["time_to_goal_s"].as_f64().unwrap();
    assert!(
        (t - calm_t).abs() < 1.0,
        "time to goal {t} s, {calm_t} s without crashes"
    );
    let path = |dir: &Path| -> Vec<[f64; 2]> {
        let rows = common::csv(&dir.join("trajectory.csv"));
        rows.iter()
            .map(|r| [common::num(r, "x"), common::num(r, "y")])
            .collect()
    };
    let (restarted, calm) = (path(dir.path()), path(calm.path()));
    // A restart loses the EKF's covariance and the MPC's warm start: the path moves by
    // centimetres (2026-11-27: 0.021-0.022 m in three runs, under 0.01 m in two; 0.061 m
    // in a fresh-clone CI run at 3edef84, 2026-12-02, a busy hour: each kill lands at a
    // simulated time the machine's speed decides, after `wait_until`; 0.004-0.124 m in
    // four runs beside a fleet's on 2026-12-04, whose kills landed later still); a
    // restarted process that started over from the scenario's start would be metres off.
    assert_eq!(restarted.len(), calm.len());
    let apart_m = restarted
        .iter()
        .zip(&calm)
        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
        .fold(0.0, f64::max);
    eprintln!("the restarted run strays {apart_m} m from the calm one");
    assert!(
        apart_m < 0.3,
        "the restarted run strays {apart_m} m from the calm one"
    );
}

#[test]
fn a_role_process_dying_inside_a_wrapper_is_caught_by_dead_node_detection() {
    let _machine = common::machine_alone();
    let dir = tempfile::tempdir().unwrap();
    let exe = env!("CARGO_BIN_EXE_scmpc");
    // The wrapper outlives the estimator it starts: its exit status says nothing.
    let file = dir.path().join("wrapped.toml");
    std::fs::write(
        &file,
        format!(
            "duration_s = 30.0\n[[swap]]\ntime_s = 0.5\nrole = \"estimator\"\n\
             command = [\"sh\", \"-c\", \"\\\"$0\\\" estimator; exec sleep 60\", \"{exe}\"]\n"
        ),
    )
    .unwrap();
    let run_dir = dir.path().join("run");
    let mut child = spawn_run(&run_dir, &[file.to_str().unwrap(), "--mode", "realtime"]);
    let mut wrapper = None;
    assert!(
        wait_for(Duration::from_secs(10), || {
            wrapper = events(&run_dir)
                .iter()
                .find(|e| e["event"] == "swapped")
                .and_then(|e| e["new_pid"].as_u64());
            wrapper.is_some()
        }),
        "the wrapped estimator never took over"
    );
    let wrapper = wrapper.unwrap() as u32;
    let estimator = *common::children_of(wrapper)
        .first()
        .expect("the wrapper has no child");
    sigkill(estimator);
    assert!(
        wait_for(Duration::from_secs(5), || events(&run_dir)
            .iter()
            .any(|e| e["event"] == "restarted" && e["role"] == "estimator")),
        "the estimator was not restarted: {:#?}",
        events(&run_dir)
    );
    // SAFETY: interrupting the run this test started.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    child.wait().unwrap();
    let ev = events(&run_dir);
    let dead = ev
        .iter()
        .find(|e| e["event"] == "dead_node")
        .unwrap_or_else(|| panic!("no dead node seen: {ev:#?}"));
    assert_eq!(dead["role"], "estimator");
    assert_eq!(dead["child_killed"], wrapper);
    let s = summary(&run_dir);
    assert_eq!(s["outcome"], "interrupted");
    assert_eq!(s["restarts"], 1);
    assert!(
        !runtime::ipc::process_alive(wrapper),
        "the wrapper still runs"
    );
    assert!(s["leftover_files"].as_array().unwrap().is_empty());
}

/// The size of a page: a write system call the kernel stops for a fatal signal stops
/// between two pages (docs/design.md, "Records of a run that died").
const PAGE_BYTES: usize = 4096;

/// The records of a run whose orchestrator was killed: every CSV file and `events.jsonl`
/// ends on a whole line (or, when the kill landed inside a write, is cut at a page
/// boundary after whole lines), `run.mcap` is read record by record by the `mcap` package
/// up to the cut, and the directory says the run did not finish. In real time, killed at
/// `kill_time_s` (simulated), `trajectory.csv` and `run.mcap` reach within a second of the
/// kill (in lockstep a second of wall time is tens of simulated seconds).
fn records_survive(dir: &Path, kill_time_s: Option<f64>) {
    assert!(dir.join(record::INCOMPLETE).exists());
    assert!(!dir.join("summary.json").exists());
    for file in [
        "trajectory.csv",
        "plans.csv",
        "predictions.csv",
        "events.jsonl",
    ] {
        let text = std::fs::read_to_string(dir.join(file)).unwrap();
        let tail = &text[text.len().saturating_sub(120)..];
        assert!(
            text.ends_with('\n') || text.len().is_multiple_of(PAGE_BYTES),
            "{file} ends inside a line, {} bytes, not at a page boundary: {tail:?}",
            text.len()
        );
        let whole = &text[..text.rfind('\n').map_or(0, |end| end + 1)];
        if file.ends_with(".csv") {
            let columns = |line: &str| line.split(',').count();
            let header = columns(whole.lines().next().unwrap());
            assert!(whole.lines().all(|l| columns(l) == header), "{file}");
        }
    }
    for event in common::events(dir) {
        assert!(event["event"].is_string(), "{event}");
    }
    let mcap = common::python::read_mcap(dir, true);
    assert_eq!(mcap[""]["cut"], true, "the file was not cut: {mcap}");
    let Some(kill_time_s) = kill_time_s else {
        return;
    };
    let trajectory = common::csv(&dir.join("trajectory.csv"));
    let columns = trajectory[0].len();
    let last_whole = trajectory.iter().rev().find(|row| row.len() == columns);
    let recorded_s = common::num(last_whole.unwrap(), "t");
    assert!(
        recorded_s >= kill_time_s - 1.0,
        "trajectory.csv ends at {recorded_s} s, killed at {kill_time_s} s"
    );
    let truth_ns = mcap["/robot/truth"]["log_time_ns"].as_array().unwrap();
    let mcap_s = truth_ns.last().unwrap().as_f64().unwrap() / 1e9;
    assert!(
        mcap_s >= kill_time_s - 1.0,
        "run.mcap ends at {mcap_s} s, killed at {kill_time_s} s"
    );
}

/// SIGKILLs the orchestrator alone of a run in `mode`; its role processes must stop the
/// robot (real time) and exit within `exit_within` (docs/running.md: 2 s in real time, the
/// grace for braking included; 0.5 s in lockstep), the records must hold the run up to a
/// second before the kill in whole lines, and the next run must remove the dead run's
/// files.
fn orchestrator_killed(mode: &str, exit_within: Duration) {
    use runtime::ipc::{TRUTH, create_node, open_topic, process_alive};
    let prefix = common::unique_prefix("orphan");
    let dir = tempfile::tempdir().unwrap();
    let args = [
        "--mode",
        mode,
        "--set",
        "duration_s=600",
        "--prefix",
        &prefix,
    ];
    let mut child = common::spawn_run(dir.path(), &args);
    let roles: Vec<u32> = ["plant", "estimator", "mpc", "dfl"]
        .iter()
        .map(|role| wait_for_pid(dir.path(), role))
        .collect();
    let node = create_node(&prefix, "tap", false).unwrap();
    let tap = open_topic::<protocol::GroundTruth>(&node, protocol::FIRST_ROBOT, TRUTH)
        .unwrap()
        .receiver()
        .unwrap();
    let mut poses = Vec::new();
    // (tick, simulated time in s, pose)
    let drain = |poses: &mut Vec<(u64, f64, [f64; 3])>| {
        while let Ok(Some((t, _))) = tap.receive() {
            poses.push((t.header.tick, t.header.time_s, t.pose));
        }
        poses.last().map_or(0, |(tick, ..)| *tick)
    };
    assert!(
        wait_for(Duration::from_secs(10), || drain(&mut poses) >= 600),
        "the run never reached t = 3 s"
    );
    let killed = std::time::Instant::now();
    common::sigkill(child.id());
    child.wait().unwrap();
    let killed_at = poses.len();
    let kill_time_s = poses[killed_at - 1].1;
    let all_gone = wait_for(exit_within.saturating_sub(killed.elapsed()), || {
        drain(&mut poses);
        roles.iter().all(|pid| !process_alive(*pid))
    });
    assert!(
        all_gone,
        "role processes still alive {exit_within:?} after the orchestrator died: {:?}",
        roles
            .iter()
            .filter(|pid| process_alive(**pid))
            .collect::<Vec<_>>()
    );
    records_survive(dir.path(), (mode == "realtime").then_some(kill_time_s));
    drain(&mut poses);
    drop((tap, node));
    if mode == "realtime" {
        // Braked to rest before the plant stopped: its last poses do not move.
        let after = &poses[killed_at..];
        assert!(
            after.len() > 20,
            "the plant stopped at once: {}",
            after.len()
        );
        let [x, y, _] = after[after.len() - 1].2;
        for (_, _, [xi, yi, _]) in &after[after.len() - 10..] {
            assert!((xi - x).hypot(yi - y) < 1e-9, "still moving at the end");
        }
        let [x0, y0, _] = after[0].2;
        assert!(
            (x - x0).hypot(y - y0) > 1e-3,
            "it was not moving when killed"
        );
    }
    let next = tempfile::tempdir().unwrap();
    common::run(&[
        "run",
        "--set",
        "duration_s=1",
        "--out",
        next.path().to_str().unwrap(),
    ]);
    assert_eq!(summary(next.path())["outcome"], "timeout");
    assert!(
        leftovers(&prefix).is_empty(),
        "the dead run's files are still there: {:?}",
        leftovers(&prefix)
    );
}

#[test]
fn when_the_orchestrator_is_killed_in_real_time_the_robot_brakes_to_rest_and_every_process_exits() {
    let _machine = common::machine_alone();
    orchestrator_killed("realtime", Duration::from_secs(2));
}

#[test]
fn when_the_orchestrator_is_killed_in_lockstep_every_process_exits() {
    let _machine = common::machine_shared();
    orchestrator_killed("lockstep", Duration::from_millis(500));
}

/// `scmpc ARGS` signalled with `signal` once its work has begun (it has made its `--out`
/// directory or written to stderr, and, when it `spawns` processes, started one): it must
/// exit with `code`, say why on stderr (`interrupted by NAME`) unless it ends normally on
/// the signal, leave none of the processes it had started, and no shared-memory file of
/// its own (`scmpc<pid>x...`: iceoryx2 resources, which `bench` and the agent open; sweep,
/// fuzz and figures run threads in process and open none).
fn command_stopped_by(args: &[&str], signal: i32, name: &str, code: i32, spawns: bool) {
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut command = scmpc();
    command.args(args);
    if args[0] != "host" {
        command.arg("--out").arg(&out);
    }
    let mut child = command
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id();
    let said = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let reader = {
        let (said, mut stderr) = (said.clone(), child.stderr.take().unwrap());
        std::thread::spawn(move || {
            let mut byte = [0u8; 1];
            while let Ok(1) = stderr.read(&mut byte) {
                said.lock().unwrap().push(byte[0] as char);
            }
        })
    };
    let begun = || {
        (out.exists() || said.lock().unwrap().contains('\n'))
            && (!spawns || !common::children_of(pid).is_empty())
    };
    assert!(
        wait_for(Duration::from_secs(20), begun),
        "{args:?} never began"
    );
    let children = common::children_of(pid);
    assert_eq!(
        children.is_empty(),
        !spawns,
        "{args:?}: children {children:?}"
    );
    // SAFETY: signalling the command this test started.
    unsafe { libc::kill(pid as i32, signal) };
    let status = child.wait().unwrap();
    reader.join().unwrap();
    let stderr = said.lock().unwrap().clone();
    assert_eq!(status.code(), Some(code), "{args:?} {name}: {stderr}");
    if code != 0 {
        assert!(
            stderr.contains(&format!("interrupted by {name}")),
            "{args:?}: {stderr}"
        );
    }
    let left: Vec<u32> = children
        .into_iter()
        .filter(|c| runtime::ipc::process_alive(*c))
        .collect();
    assert!(left.is_empty(), "{args:?} {name}: processes left {left:?}");
    let own = format!("scmpc{pid}x");
    let files: Vec<_> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains(&own))
        .collect();
    assert!(files.is_empty(), "{args:?} {name}: {files:?}");
}

#[test]
fn sweep_fuzz_figures_bench_and_host_stop_cleanly_on_sigterm_and_sighup() {
    let _machine = common::machine_alone();
    for (signal, name) in [(libc::SIGTERM, "SIGTERM"), (libc::SIGHUP, "SIGHUP")] {
        command_stopped_by(&["fuzz", "--count", "2000"], signal, name, 1, false);
        command_stopped_by(&["sweep", "--seeds", "500"], signal, name, 1, false);
        command_stopped_by(&["figures"], signal, name, 1, false);
        // Signalled during its first ping-pong, whose partner is a process of its own.
        command_stopped_by(&["bench"], signal, name, 1, true);
        let listen = "tcp/127.0.0.1:0";
        command_stopped_by(
            &["host", "--name", "h", "--listen", listen],
            signal,
            name,
            0,
            false,
        );
    }
}

#[test]
fn sigterm_and_sighup_end_a_real_time_run_as_ctrl_c_does_and_the_summary_names_the_signal() {
    let _machine = common::machine_alone();
    for (signal, name) in [(libc::SIGTERM, "SIGTERM"), (libc::SIGHUP, "SIGHUP")] {
        let prefix = common::unique_prefix("signal");
        let dir = tempfile::tempdir().unwrap();
        let args = [
            "--mode",
            "realtime",
            "--set",
            "duration_s=600",
            "--prefix",
            &prefix,
        ];
        let mut child = spawn_run(dir.path(), &args);
        let roles: Vec<u32> = ["plant", "estimator", "mpc", "dfl"]
            .iter()
            .map(|role| wait_for_pid(dir.path(), role))
            .collect();
        let recorded_s = || {
            let text = std::fs::read_to_string(dir.path().join("trajectory.csv")).unwrap();
            let last = text.lines().last().unwrap_or_default();
            last.split(',').next().and_then(|t| t.parse::<f64>().ok())
        };
        assert!(
            wait_for(Duration::from_secs(10), || recorded_s() >= Some(3.0)),
            "{name}: the run never reached t = 3 s"
        );
        let sent = std::time::Instant::now();
        // SAFETY: signalling the run this test started.
        unsafe { libc::kill(child.id() as i32, signal) };
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(1), "{name}: {status:?}");
        let s = summary(dir.path());
        assert_eq!(s["outcome"], "interrupted", "{name}");
        assert_eq!(s["interrupted_by"], name);
        assert!(s["leftover_files"].as_array().unwrap().is_empty(), "{name}");
        assert!(
            leftovers(&prefix).is_empty(),
            "{name}: {:?}",
            leftovers(&prefix)
        );
        let end = events(dir.path()).pop().unwrap();
        assert_eq!(
            (&end["event"], &end["signal"]),
            (&"end".into(), &name.into())
        );
        assert!(!dir.path().join(record::INCOMPLETE).exists());
        let roles_gone = wait_for(
            Duration::from_secs(2).saturating_sub(sent.elapsed()),
            || roles.iter().all(|pid| !runtime::ipc::process_alive(*pid)),
        );
        assert!(roles_gone, "{name}: a role process outlived the run by 2 s");
    }
}

#[test]
fn a_failed_producer_aborts_the_run_when_restarts_are_off_or_used_up() {
    let _machine = common::machine_shared();
    for policy in ["supervision.restart=never", "supervision.max_restarts=0"] {
        let dir = tempfile::tempdir().unwrap();
        let out = common::run(&[
            "run",
            "--set",
            "fault.estimator_nan_from_s=5",
            "--set",
            policy,
            "--out",
            dir.path().to_str().unwrap(),
        ]);
        assert_ne!(out.status.code(), Some(0), "{policy}");
        let s = summary(dir.path());
        assert_eq!(s["outcome"], "aborted", "{policy}");
        assert_eq!(s["restarts"], 0, "{policy}");
        assert!(s["leftover_files"].as_array().unwrap().is_empty());
        let ev = events(dir.path());
        for event in ["refused_too_long", "crashed"] {
            assert!(
                common::has_event(&ev, event, "estimator"),
                "{policy}: no `{event}` in {ev:#?}"
            );
        }
        assert!(
            !common::has_event(&ev, "restarted", "estimator"),
            "{policy}"
        );
    }
}

#[test]
fn realtime_dfl_killed_at_3_s_is_restarted_and_commands_resume_within_0_2_s() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        kill_role_during_run(
            dir.path(),
            &["--mode", "realtime", "--set", "duration_s=10"],
            "dfl",
            3.0,
        );
        let s = summary(dir.path());
        let ev = events(dir.path());
        for event in ["crashed", "restarted"] {
            assert!(
                common::has_event(&ev, event, "dfl"),
                "no `{event}` of the dfl in {ev:#?}"
            );
        }
        // While no DFL runs the plant holds the last command: at most 40 ticks (0.2 s) go
        // without one but in a stall of the machine the watcher saw (at most 1 % of the
        // ticks: `stalls::Seen::judge`), and the robot stays clear of the obstacle. (A CI run
        // at 261cbaf, in a slow hour, had 44; 11-12 is usual.)
        let gaps = s["record_gaps"].as_u64().unwrap();
        assert!(gaps >= 1, "no tick without a command");
        // Each gap names the silent process: the DFL, while the plant and its sensor went on.
        let gap_events: Vec<_> = ev.iter().filter(|e| e["event"] == "record_gap").collect();
        assert_eq!(gap_events.len() as u64, gaps);
        let past_budget: Vec<_> = (common::stalls::faults(&ev).into_iter())
            .filter(|f| f.what == "tick without a command")
            .skip(40)
            .collect();
        machine.judge_faults(&ev, &past_budget)?;
        for gap in gap_events {
            let missing = gap["missing"].as_array().unwrap();
            let names = |topic: &str| missing.iter().any(|m| m == topic);
            assert!(
                names("actuation") && !names("truth") && !names("measurement"),
                "{gap}"
            );
        }
        // Every other tick of the 10 s is recorded whole.
        assert_eq!(s["ticks"].as_u64().unwrap() + gaps, 2000);
        assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
        assert_eq!(s["restarts"], 1);
        assert!(s["leftover_files"].as_array().unwrap().is_empty());
        Ok(())
    })
}

/// A slow estimator (2 ms of a 5 ms tick) stopped for 50 ms: the DFL brakes alone, at each
/// tick's start, and once the estimator goes on, every tick is commanded from its estimate
/// again, but in the spells a stall of the machine begins. (Before the DFL kept braking alone to the end: each tick's brake came before the
/// estimate of the tick, which was then too late. A CI run at aae8d80 saw it after a stall
/// of the machine.)
#[test]
fn a_slow_estimator_stopped_for_50_ms_is_braked_for_then_commands_come_from_its_estimates_again() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        let prefix = common::unique_prefix("slowstop");
        let args = [
            "--mode",
            "realtime",
            "--no-mcap",
            "--set",
            "duration_s=3",
            "--set",
            "fault.estimator_delay_ms=2",
            "--prefix",
            &prefix,
        ];
        let mut child = common::spawn_run(dir.path(), &args);
        let pid = wait_for_pid(dir.path(), "estimator");
        common::SimulatedClock::of(&prefix).wait_until(1.0);
        assert!(common::is_role_process(pid, "estimator", &prefix));
        // SAFETY: signals to a process of the run this test started.
        unsafe { libc::kill(pid as i32, libc::SIGSTOP) };
        // The fault itself: the estimator stopped for 50 ms, 10 ticks.
        std::thread::sleep(Duration::from_millis(50));
        unsafe { libc::kill(pid as i32, libc::SIGCONT) };
        // It ends at its 3 s, short of the goal (a run that times out exits 1).
        assert!(child.wait().unwrap().code().is_some());
        let rows = common::csv(&dir.path().join("trajectory.csv"));
        let braked: Vec<u64> = (rows.iter())
            .filter(|r| r["mode"] == "brake")
            .map(|r| (common::num(r, "t") / 0.005).round() as u64)
            .collect();
        assert!(
            braked.iter().any(|&tick| (200..300).contains(&tick)),
            "the DFL never braked alone"
        );
        // Before, all 200 ticks of the last second braked. A stall of the machine may still
        // silence the estimator, and each spell it starts is judged against the stalls;
        // none lasts longer than a stall could make it.
        let spells = spells_braked_alone(&braked, 400..600);
        let long = (spells.iter()).find(|(first, last)| last - first + 1 > MOST_TICKS_A_SPELL);
        assert!(
            long.is_none(),
            "braked alone too long for a stall to explain, ticks {long:?}: {spells:?}"
        );
        let faults: Vec<_> = spells.into_iter().map(spell_began).collect();
        machine.judge_faults(&common::events(dir.path()), &faults)?;
        let loop_us = summary(dir.path())["loop_latency_us"]["p50"]
            .as_f64()
            .unwrap();
        assert!(
            (2000.0..5000.0).contains(&loop_us),
            "sensor to actuator {loop_us} us"
        );
        Ok(())
    })
}

/// The spells of braking alone (first and last tick) of the sorted `braked` ticks that
/// reach into `judged`.
fn spells_braked_alone(braked: &[u64], judged: std::ops::Range<u64>) -> Vec<(u64, u64)> {
    let mut spells: Vec<(u64, u64)> = Vec::new();
    for &tick in braked {
        match spells.last_mut() {
            Some((_, last)) if *last + 1 == tick => *last = tick,
            _ => spells.push((tick, tick)),
        }
    }
    spells.retain(|&(first, last)| first < judged.end && judged.start <= last);
    spells
}

/// The longest spell of braking alone a stall of the machine may give with a 2 ms
/// estimator: a stall of `S` ms brakes about `S / 5 - 3` ticks while it lasts
/// ([`dfl::SILENT_TICKS`] silent first) and `0.13 S` after it, while the estimator
/// catches up on what queued meanwhile, 2 ms an estimate; 40 ticks is a stall of about
/// 120 ms. A DFL braking for good after a stall brakes to the end.
const MOST_TICKS_A_SPELL: u64 = 40;

/// The fault that began a spell of braking alone (`(first, last)` tick): the DFL brakes
/// once the estimator has been silent for [`dfl::SILENT_TICKS`], so its cause (a stall of
/// the estimator, or of what it waits for) began within those ticks before its first. The
/// ticks after its first are the estimator catching up, longer than the two ticks after a
/// stall a judge excuses.
fn spell_began((first, last): (u64, u64)) -> common::stalls::Fault {
    common::stalls::Fault {
        what: "braked alone",
        tick: first.saturating_sub(dfl::SILENT_TICKS),
        ticks: dfl::SILENT_TICKS + 1,
        detail: format!("ticks {first}..={last} braked alone"),
    }
}

#[test]
fn a_slow_estimator_in_real_time_delays_every_command_and_one_slower_than_a_tick_brakes_to_rest() {
    common::until_judged(|machine| {
        let run = |delay_ms: &str| {
            let dir = tempfile::tempdir().unwrap();
            let delay = format!("fault.estimator_delay_ms={delay_ms}");
            let out = common::run(&[
                "run",
                "--mode",
                "realtime",
                "--set",
                "duration_s=3",
                "--set",
                &delay,
                "--out",
                dir.path().to_str().unwrap(),
            ]);
            assert!(out.status.code().is_some());
            let s = summary(dir.path());
            (dir, s)
        };
        // 2 ms of a 5 ms tick: every command 2 ms later, and no tick without an estimate,
        // record gap or deadline miss but in a stall of the machine the watcher saw (at most
        // 1 % of the ticks: `stalls::Seen::judge`). (Before issue 59 up to 6 of each were
        // allowed unwatched: CI, 2026-11-26, a slow hour, had 2 ticks of 600 without an
        // estimate.) 6 ms must go without in more than 10 % of the ticks (512 of 600 in a
        // direct run).
        let (dir, s) = run("2");
        let loop_us = s["loop_latency_us"]["p50"].as_f64().unwrap();
        // (A p50 far below 2 ms, seen twice in CI on 2026-12-01, was the DFL braking alone to
        // the end after a stall of the machine: the test below provokes it.)
        assert!(
            (2000.0..5000.0).contains(&loop_us),
            "sensor to actuator {loop_us} us: {} (restarts {}, gaps {}, ticks without an \
         estimate {}, misses {})",
            s["loop_latency_us"],
            s["restarts"],
            s["record_gaps"],
            s["ticks_without_estimate"],
            s["deadline_misses"]
        );
        let events = common::events(dir.path());
        let mut faults = common::stalls::faults(&events);
        // (A tick commanded without an estimate is recorded with an estimate of NaN.)
        for row in common::csv(&dir.path().join("trajectory.csv")) {
            if row["x_hat"] == "NaN" {
                let tick = (common::num(&row, "t") / 0.005).round() as u64;
                faults.push(common::stalls::Fault::at(
                    "tick without an estimate",
                    tick,
                    String::new(),
                ));
            }
        }
        machine.judge_faults(&events, &faults)?;
        let hiccups = s["ticks"].as_u64().unwrap() / 100;
        // 6 ms: the estimates fall behind the clock, and the DFL brakes on its own clock.
        let (_dir, s) = run("6");
        let without = s["ticks_without_estimate"].as_u64().unwrap();
        assert!(
            without > 10 * hiccups,
            "{without} ticks without an estimate"
        );
        assert!(
            s["commands"]["brake"].as_u64().unwrap() > 0,
            "{}",
            s["commands"]
        );
        assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
        assert_ne!(s["outcome"], "reached");
        Ok(())
    })
}
