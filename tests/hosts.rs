//! Roles on another host (docs/hosts.md): a real `scmpc host` agent on loopback, real
//! Zenoh between it and the orchestrator, real role processes on both "hosts".

use crate::common;

use common::agent::Agent;
use common::{events, leftovers, run, stalls, stderr, summary, wait_for};
use record::schema::Table;
use runtime::ipc::process_alive;
use std::path::Path;
use std::process::{Child, Output};
use std::time::Duration;

/// The paper scenario, made short: it reaches its goal at 7.46 s (lockstep).
const SHORT: [&str; 4] = ["--set", "mpc.r_diag=[3,3]", "--set", "duration_s=10"];

impl Agent {
    /// Starts `scmpc run --mode realtime ARGS` into `dir` in the background with the MPC
    /// on this agent's host `compute`.
    fn spawn_realtime_run(&self, dir: &Path, args: &[&str]) -> Child {
        let host = format!("compute={}", self.endpoint);
        let placed = [
            "--mode",
            "realtime",
            "--host",
            &host,
            "--set",
            "hosts.mpc=compute",
        ];
        common::spawn_run(dir, &[&placed[..], args].concat())
    }

    /// `scmpc run ARGS` with the roles `placed` on this agent's host `name`, into `dir`.
    fn run(&self, name: &str, placed: &[&str], dir: &Path, args: &[&str]) -> Output {
        let host = format!("{name}={}", self.endpoint);
        let mut all = vec!["run", "--host", &host, "--out", dir.to_str().unwrap()];
        let sets: Vec<String> = placed.iter().map(|r| format!("hosts.{r}={name}")).collect();
        for set in &sets {
            all.extend(["--set", set]);
        }
        all.extend(args);
        run(&all)
    }
}

fn read(path: &Path) -> Vec<u8> {
    std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Runs `scenario_args` on one host and with `placed` on agent `compute`; asserts both
/// trajectories are the same bytes (and the plans the same) and the summary names each role's host.
fn assert_same_run_across_hosts(agent: &Agent, placed: &[&str], scenario_args: &[&str]) {
    let one = tempfile::tempdir().unwrap();
    let two = tempfile::tempdir().unwrap();
    let out = run(&[
        &["run", "--out", one.path().to_str().unwrap()],
        scenario_args,
    ]
    .concat());
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let out = agent.run("compute", placed, two.path(), scenario_args);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(
        read(&one.path().join("trajectory.csv")) == read(&two.path().join("trajectory.csv")),
        "trajectory.csv differs with {placed:?} on another host"
    );
    assert_eq!(
        common::plans_made(one.path()),
        common::plans_made(two.path()),
        "plans.csv differs with {placed:?} on another host"
    );
    let s = summary(two.path());
    assert_eq!(s["outcome"], "reached");
    for role in placed {
        assert_eq!(s["hosts"][role], "compute", "{s}");
    }
    assert!(s["hosts"].get("plant").is_none(), "{s}");
    assert!(s["links"]["compute"]["round_trip_us"].as_f64().unwrap() > 0.0);
    let spawned_on = |role: &str| {
        events(two.path())
            .into_iter()
            .find(|e| e["event"] == "spawned" && e["role"] == role)
            .map(|e| e["host"].clone())
    };
    for role in placed {
        assert_eq!(spawned_on(role), Some("compute".into()), "{role}");
    }
    assert_eq!(spawned_on("dfl"), Some(serde_json::Value::Null));
}

#[test]
fn in_lockstep_the_paper_with_the_mpc_on_another_host_gives_the_same_bytes() {
    let _machine = common::machine_shared();
    let agent = Agent::plain("compute");
    assert_same_run_across_hosts(&agent, &["mpc"], &["paper"]);
    agent.assert_left_nothing(Duration::from_secs(5));
}

#[test]
fn in_lockstep_the_field_with_the_mpc_and_the_planner_on_another_host_gives_the_same_bytes() {
    let _machine = common::machine_shared();
    let agent = Agent::plain("compute");
    assert_same_run_across_hosts(&agent, &["mpc", "planner"], &["field"]);
}

#[test]
fn in_lockstep_crossing_with_the_tracker_on_another_host_gives_the_same_bytes() {
    let _machine = common::machine_shared();
    let agent = Agent::plain("compute");
    assert_same_run_across_hosts(&agent, &["tracker"], &["crossing"]);
}

#[test]
fn an_agent_serves_run_after_run_and_a_swap_of_a_remote_role_runs_on_its_host() {
    let _machine = common::machine_shared();
    let agent = Agent::plain("compute");
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("swap.toml");
    std::fs::write(
        &file,
        "name = \"remote swap\"\n[[swap]]\ntime_s = 3.0\nrole = \"mpc\"\n\
         command = [\"scmpc\", \"mpc\", \"--set\", \"mpc.horizon=10\"]\n",
    )
    .unwrap();
    let file = file.to_str().unwrap();
    for run_no in 0..2 {
        let out_dir = dir.path().join(format!("run{run_no}"));
        let out = agent.run(
            "compute",
            &["mpc"],
            &out_dir,
            &[&[file][..], &SHORT].concat(),
        );
        assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
        let s = summary(&out_dir);
        assert_eq!(s["outcome"], "reached");
        assert_eq!(s["swaps"], 1, "{s}");
        let ev = events(&out_dir);
        let on_host = ev
            .iter()
            .filter(|e| e["event"] == "spawned" && e["role"] == "mpc")
            .all(|e| e["host"] == "compute");
        assert!(on_host, "an MPC ran on the orchestrator's host: {ev:#?}");
        let plans = Table::read(&out_dir.join("plans.csv")).unwrap();
        let epochs = plans.numbers("mpc_epoch").unwrap();
        assert!(epochs.contains(&0.0) && epochs.contains(&1.0), "no swap");
    }
}

/// The real-time run in `dir`, held `machine` alone, asserted clean: reached, clear of
/// every obstacle, no deadline missed and no tick lost but in a stall of the machine (2
/// record gaps, ticks 1998 of 2000, in a fresh-clone CI run on 2026-11-27) ([`common::Alone::judge`]).
fn assert_clean_realtime(
    machine: &common::Alone,
    dir: &Path,
) -> Result<serde_json::Value, common::stalls::TooBusy> {
    let s = summary(dir);
    assert_eq!(s["outcome"], "reached", "{s}");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0);
    machine.judge(&events(dir))?;
    Ok(s)
}

#[test]
fn in_real_time_the_mpc_on_another_host_misses_no_deadline_and_a_stranger_cannot_inject() {
    common::until_judged(|machine| {
        let agent = Agent::plain("compute");
        let dir = tempfile::tempdir().unwrap();
        let prefix = common::unique_prefix("stranger");
        let run_dir = dir.path().join("run");
        let mut child =
            agent.spawn_realtime_run(&run_dir, &[&["--prefix", &prefix][..], &SHORT].concat());
        common::wait_for_pid(&run_dir, "mpc");
        // The threads that carry the samples between the hosts run at the loop's priority:
        // each bridge's two (names cut to 15 bytes) and Zenoh's workers.
        for (pid, host) in [(agent.pid(), "compute"), (child.id(), "orchestrator")] {
            let bridge = [format!("bridge-in-{host}"), format!("bridge-out-{host}")]
                .map(|name| name[..name.len().min(15)].to_string());
            let mut carriers: Vec<&str> = bridge.iter().map(String::as_str).collect();
            carriers.extend(common::ZENOH_WORKERS);
            common::assert_threads_at_the_control_tier(pid, &carriers);
        }
        // A Zenoh peer that is not a bridge of the run publishes estimates for the host.
        let stranger = {
            use zenoh::Wait;
            let mut config = zenoh::Config::default();
            config
                .insert_json5("connect/endpoints", &format!("[\"{}\"]", agent.endpoint))
                .unwrap();
            config
                .insert_json5("scouting/multicast/enabled", "false")
                .unwrap();
            let session = zenoh::open(config).wait().unwrap();
            let key = hosts::keys::to_host(
                &hosts::keys::run_of_prefix(&prefix),
                "compute",
                protocol::FIRST_ROBOT,
                "estimate",
            );
            let publisher = session.declare_publisher(key).wait().unwrap();
            // Once the host's bridge takes the key.
            assert!(wait_for(Duration::from_secs(10), || {
                publisher
                    .matching_status()
                    .wait()
                    .is_ok_and(|m| m.matching())
            }));
            let forged = vec![0x5a_u8; 512];
            for _ in 0..20 {
                publisher.put(forged.clone()).wait().unwrap();
                publisher
                    .put(forged.clone())
                    .attachment(vec![7_u8; 32])
                    .wait()
                    .unwrap();
            }
            drop(publisher);
            session
        };
        assert!(child.wait().unwrap().success());
        drop(stranger);
        let s = assert_clean_realtime(machine, &run_dir)?;
        let link = &s["links"]["compute"];
        let refused = link["host_bridge"]["refused_tag"].as_u64().unwrap();
        assert_eq!(refused, 40, "forged samples not all refused: {link}");
        assert!(link["host_bridge"]["received"].as_u64().unwrap() > 100);
        assert!(s["orchestrator_bridge"]["received"].as_u64().unwrap() > 100);
        assert!(leftovers(&prefix).is_empty());
        Ok(())
    })
}

#[test]
fn a_host_clock_3_s_off_is_measured_within_1_ms_and_one_ahead_misses_no_deadline_in_real_time() {
    common::until_judged(|machine| {
        // Ahead in real time; behind in lockstep, which measures the clock as it joins alike.
        for (offset_ms, mode) in [(3000.0, "realtime"), (-3000.0_f64, "lockstep")] {
            let offset = format!("{offset_ms}");
            let agent = Agent::start("compute", "tcp", &[], &[("SCMPC_CLOCK_OFFSET_MS", &offset)]);
            let dir = tempfile::tempdir().unwrap();
            let out = agent.run(
                "compute",
                &["mpc"],
                dir.path(),
                &[&["--mode", mode][..], &SHORT].concat(),
            );
            assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
            let s = match mode {
                "realtime" => assert_clean_realtime(machine, dir.path())?,
                _ => summary(dir.path()),
            };
            // The agent's clock runs `offset` ahead: the correction takes it back.
            let correction_ms = s["links"]["compute"]["clock_correction_ms"]
                .as_f64()
                .unwrap();
            assert!(
                (correction_ms + offset_ms).abs() < 1.0,
                "offset {offset_ms} ms measured as a correction of {correction_ms} ms"
            );
        }
        Ok(())
    })
}

/// A real-time run of `SHORT` (at most `duration_s` long, ended once the robot is held at
/// its goal) with the MPC on `agent` and `fault`; returns its directory and summary.
fn link_fault_run(
    agent: &Agent,
    fault: &str,
    duration_s: &str,
) -> (tempfile::TempDir, serde_json::Value) {
    let dir = tempfile::tempdir().unwrap();
    let duration = format!("duration_s={duration_s}");
    let out = agent.run(
        "compute",
        &["mpc"],
        dir.path(),
        &[
            "--mode",
            "realtime",
            "--set",
            "mpc.r_diag=[3,3]",
            "--set",
            &duration,
            "--set",
            "robot.final_approach=settle",
            "--set",
            fault,
        ],
    );
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    let s = summary(dir.path());
    assert_eq!(s["outcome"], "reached", "{fault}: {s}");
    assert!(s["min_clearance_m"].as_f64().unwrap() > 0.0, "{fault}");
    (dir, s)
}

/// `plans.csv` as `(sample, arrival after t_k in ms or None, deadline met, fallback)`.
fn verdicts(dir: &Path) -> Vec<(u64, Option<f64>, bool, String)> {
    common::csv(&dir.join("plans.csv"))
        .iter()
        .filter(|row| !row["deadline_met"].is_empty())
        .map(|row| {
            (
                common::num(row, "sample") as u64,
                row["arrival_ms"].parse().ok(),
                row["deadline_met"] == "true",
                row["fallback"].clone(),
            )
        })
        .collect()
}

#[test]
fn a_link_60_ms_slow_flags_every_late_plan_and_the_robot_still_reaches_the_goal() {
    let _machine = common::machine_alone();
    let agent = Agent::plain("compute");
    let (dir, s) = link_fault_run(&agent, "fault.link_delay_ms=60", "12");
    let verdicts = verdicts(dir.path());
    // Held at its goal at about 9.5 s: some 190 samples, every one late.
    assert!(verdicts.len() > 150, "{} samples", verdicts.len());
    // Ts = 50 ms: a plan is in time iff it came within its own sample.
    for (sample, arrival_ms, met, _) in &verdicts {
        assert_eq!(
            *met,
            arrival_ms.is_some_and(|a| a < 50.0),
            "sample {sample}"
        );
        assert!(!met, "sample {sample} came in time over a 60 ms link");
    }
    assert_eq!(s["deadline_misses"], verdicts.len() as u64);
}

#[test]
fn a_link_down_from_2_to_4_s_gives_the_shifted_plan_then_the_brake_and_flying_resumes() {
    // Samples are 50 ms: the link is down for samples 40..80 (give or take the one a plan
    // was on its way in). A plan missed outside them must have come late in a stall of the
    // machine (CI at 3bebf3a missed sample 17 once).
    let window = 39..=81;
    common::until_judged(|machine| {
        let agent = Agent::plain("compute");
        let (dir, s) = link_fault_run(&agent, "fault.link_down_s=[2, 4]", "14");
        let events = events(dir.path());
        let outside = stalls::misses_outside(&events, |k| window.contains(&k));
        machine.judge_faults(&events, &outside)?;
        let verdicts = verdicts(dir.path());
        let missed: Vec<u64> = (verdicts.iter())
            .filter(|v| !v.2 && window.contains(&v.0))
            .map(|v| v.0)
            .collect();
        let first = *missed.first().expect("no plan missed");
        assert!((39..=41).contains(&first), "first miss at sample {first}");
        assert!(missed.len() >= 38, "{missed:?}");
        // The first missing plan is met by the shifted plan at once, the brake follows
        // when the shifted plan runs out, and nominal flying comes back after.
        let fallback = |k: u64| verdicts.iter().find(|v| v.0 == k).unwrap().3.clone();
        assert_eq!(fallback(first), "shifted");
        assert!(
            missed.iter().any(|&k| fallback(k) == "brake"),
            "never braked"
        );
        let trajectory = Table::read(&dir.path().join("trajectory.csv")).unwrap();
        let (t, mode) = (
            trajectory.numbers("t").unwrap(),
            trajectory.column("mode").unwrap(),
        );
        let nominal_after = (0..t.len()).any(|i| t[i] > 4.5 && mode[i] == "nominal");
        assert!(nominal_after, "no nominal command after the link came back");
        let down = s["links"]["compute"]["host_bridge"]["down"]
            .as_u64()
            .unwrap()
            + s["orchestrator_bridge"]["down"].as_u64().unwrap();
        assert!(down > 0, "{s}");
        Ok(())
    })
}

#[test]
fn a_link_down_past_the_command_timeout_brakes_the_base_which_ramps_to_the_commands_that_come_again()
 {
    let _machine = common::machine_alone();
    let agent = Agent::plain("compute");
    let dir = tempfile::tempdir().unwrap();
    // The estimator and the DFL on the agent: from 2 s the link carries neither the
    // measurements nor the commands. The base holds its last command for 0.5 s, brakes
    // at the DFL's brake's 3 m/s^2, and at 2.7 s, still moving, is commanded again by a
    // DFL that braked to rest on its own meanwhile.
    let out = agent.run(
        "compute",
        &["estimator", "mpc", "dfl"],
        dir.path(),
        &[
            "--mode",
            "realtime",
            "--no-mcap",
            "--set",
            "mpc.r_diag=[3,3]",
            "--set",
            "duration_s=8",
            "--set",
            "fault.link_down_s=[2.0, 2.7]",
        ],
    );
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    let events = events(dir.path());
    let timeouts = (events.iter())
        .filter(|e| e["event"] == "command_timeout")
        .count();
    assert_eq!(timeouts, 1, "{events:?}");
    // The record's zeta is what drove the base each tick (the DFL's, or its watchdog's
    // while it braked and ramped): never faster a change than the input box allows.
    let trajectory = Table::read(&dir.path().join("trajectory.csv")).unwrap();
    let (t, zeta, mode) = (
        trajectory.numbers("t").unwrap(),
        trajectory.numbers("zeta").unwrap(),
        trajectory.column("mode").unwrap(),
    );
    let box_accel = 2f64.sqrt() * 3.0;
    for i in 1..t.len() {
        let rate = (zeta[i] - zeta[i - 1]).abs() / (t[i] - t[i - 1]);
        assert!(
            rate <= box_accel * 1.001,
            "zeta {} -> {} m/s at t = {} s ({} -> {})",
            zeta[i - 1],
            zeta[i],
            t[i],
            mode[i - 1],
            mode[i]
        );
    }
    // Commanded again by 2.75 s, the base was still moving: ramping to the commands.
    let i = (0..t.len())
        .find(|&i| t[i] >= 2.75)
        .expect("recorded to 2.75 s");
    assert!(
        mode[i] == "watchdog" && zeta[i] > 0.1,
        "at {} s: {} m/s in mode {}",
        t[i],
        zeta[i],
        mode[i]
    );
}

#[test]
fn a_link_losing_a_fifth_of_its_samples_still_reaches_the_goal_and_counts_the_losses() {
    let _machine = common::machine_alone();
    let agent = Agent::plain("compute");
    let (_dir, s) = link_fault_run(&agent, "fault.link_loss=0.2", "12");
    let lost = s["links"]["compute"]["host_bridge"]["lost"]
        .as_u64()
        .unwrap()
        + s["orchestrator_bridge"]["lost"].as_u64().unwrap();
    let sent = s["links"]["compute"]["host_bridge"]["sent"]
        .as_u64()
        .unwrap()
        + s["orchestrator_bridge"]["sent"].as_u64().unwrap();
    // About a fifth of what was offered to the link.
    let share = lost as f64 / (lost + sent) as f64;
    assert!(
        (0.1..0.3).contains(&share),
        "lost {lost} of {}",
        lost + sent
    );
    assert!(s["deadline_misses"].as_u64().unwrap() > 0);
}

/// A real-time run with the MPC on `agent`, whose agent is SIGKILLed once the run is 2 s
/// in; returns the run's directory, summary and the remote MPC's pid.
fn run_losing_the_host(failover: &str) -> (tempfile::TempDir, serde_json::Value, Agent, u32) {
    let mut agent = Agent::plain("compute");
    let dir = tempfile::tempdir().unwrap();
    let policy = format!("supervision.failover={failover}");
    let prefix = common::unique_prefix("lost");
    let set = ["--set", &policy, "--prefix", &prefix];
    let mut child = agent.spawn_realtime_run(dir.path(), &[&set[..], &SHORT].concat());
    let mpc = common::wait_for_pid(dir.path(), "mpc");
    common::SimulatedClock::of(&prefix).wait_until(2.0);
    agent.child.kill().unwrap();
    agent.child.wait().unwrap();
    child.wait().unwrap();
    let s = summary(dir.path());
    (dir, s, agent, mpc)
}

#[test]
fn when_the_agent_dies_with_failover_local_a_local_mpc_takes_over_and_the_goal_is_reached() {
    let _machine = common::machine_alone();
    let (dir, s, _agent, _) = run_losing_the_host("local");
    assert_eq!(s["outcome"], "reached", "{s}");
    assert!(s["links"]["compute"]["lost"].as_bool().unwrap());
    let ev = events(dir.path());
    assert!(common::has_event(&ev, "failed_over", "mpc"), "{ev:#?}");
    let failed_over = ev.iter().find(|e| e["event"] == "failed_over").unwrap();
    assert!(failed_over["host"].is_null(), "{failed_over}");
}

#[test]
fn when_the_agent_dies_without_failover_the_run_aborts_at_rest_and_leaves_nothing() {
    let _machine = common::machine_alone();
    let (dir, s, agent, mpc) = run_losing_the_host("none");
    assert_eq!(s["outcome"], "aborted", "{s}");
    // Braked to rest before the run ended: the last recorded poses do not move.
    let trajectory = Table::read(&dir.path().join("trajectory.csv")).unwrap();
    let (x, y) = (
        trajectory.numbers("x").unwrap(),
        trajectory.numbers("y").unwrap(),
    );
    let n = x.len();
    assert!(n > 20);
    for i in n - 10..n {
        assert!(
            (x[i] - x[n - 1]).hypot(y[i] - y[n - 1]) < 1e-9,
            "still moving"
        );
    }
    assert!(
        (x[n - 1] - x[0]).hypot(y[n - 1] - y[0]) > 0.5,
        "it never drove"
    );
    let ev = events(dir.path());
    assert!(ev.iter().any(|e| e["event"] == "host_lost"));
    // No process of the run on either "host" after the orphan grace, no file left.
    let mut pids: Vec<u32> = ["plant", "estimator", "dfl"]
        .iter()
        .map(|r| s["pids"][r].as_u64().unwrap() as u32)
        .collect();
    pids.push(mpc);
    assert!(
        wait_for(Duration::from_secs(3), || pids
            .iter()
            .all(|p| !process_alive(*p))),
        "still running: {:?}",
        pids.iter()
            .filter(|p| process_alive(**p))
            .collect::<Vec<_>>()
    );
    assert!(s["leftover_files"].as_array().unwrap().is_empty());
    agent.assert_left_nothing(Duration::from_secs(3));
}

#[test]
fn when_the_orchestrator_is_killed_the_remote_roles_stop_and_the_agent_serves_the_next_run() {
    let _machine = common::machine_alone();
    let agent = Agent::plain("compute");
    let dir = tempfile::tempdir().unwrap();
    let prefix = common::unique_prefix("orphan");
    let args = ["--set", "duration_s=60", "--prefix", &prefix];
    let mut child = agent.spawn_realtime_run(dir.path(), &args);
    let mpc = common::wait_for_pid(dir.path(), "mpc");
    common::SimulatedClock::of(&prefix).wait_until(1.0);
    common::sigkill(child.id());
    child.wait().unwrap();
    assert!(
        wait_for(Duration::from_secs(5), || !process_alive(mpc)),
        "the remote MPC outlived its orchestrator"
    );
    agent.wait_for_line("ended");
    agent.assert_left_nothing(Duration::from_secs(3));
    let next = tempfile::tempdir().unwrap();
    let out = agent.run("compute", &["mpc"], next.path(), &["paper"]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert_eq!(summary(next.path())["outcome"], "reached");
}

#[test]
fn plain_tcp_off_loopback_is_refused_by_the_run_and_the_agent_naming_the_option() {
    let _machine = common::machine_shared();
    let endpoint = "tcp/192.0.2.7:7447";
    let host = format!("compute={endpoint}");
    let out = run(&["run", "--set", "hosts.mpc=compute", "--host", &host]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("--insecure"), "{}", stderr(&out));
    let out = run(&["host", "--name", "compute", "--listen", endpoint]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("--insecure"), "{}", stderr(&out));
}

#[test]
fn a_host_that_does_not_answer_fails_the_run_before_tick_0_naming_it() {
    let _machine = common::machine_shared();
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .unwrap()
        .port();
    let dir = tempfile::tempdir().unwrap();
    let host = format!("compute=tcp/127.0.0.1:{port}");
    let out = run(&[
        "run",
        "--set",
        "hosts.mpc=compute",
        "--set",
        "hosts.join_timeout_s=1",
        "--host",
        &host,
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    assert!(
        stderr(&out).contains("host `compute`")
            && stderr(&out).contains("did not join")
            && stderr(&out).contains("no answer within 1s"),
        "{}",
        stderr(&out)
    );
    // It never started: no summary.
    assert!(!dir.path().join("summary.json").exists());
}

#[test]
fn over_tls_with_mutual_authentication_the_remote_run_gives_the_same_bytes() {
    let _machine = common::machine_shared();
    let certs = tempfile::tempdir().unwrap();
    let [ca, cert, key] = common::tls_files(certs.path());
    let tls = ["--tls-ca", &ca, "--tls-cert", &cert, "--tls-key", &key];
    let agent = Agent::start("compute", "tls", &tls, &[]);
    let one = tempfile::tempdir().unwrap();
    let two = tempfile::tempdir().unwrap();
    let out = run(&[&["run", "--out", one.path().to_str().unwrap()][..], &SHORT].concat());
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let out = agent.run(
        "compute",
        &["mpc"],
        two.path(),
        &[&SHORT[..], &tls].concat(),
    );
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    assert!(read(&one.path().join("trajectory.csv")) == read(&two.path().join("trajectory.csv")));
    // Mutual: the agent refuses an orchestrator whose certificate another CA signed (the
    // orchestrator itself trusts the agent's), and the orchestrator refuses an agent whose
    // certificate is not of the CA it trusts (its own is good).
    let strangers = tempfile::tempdir().unwrap();
    let [other_ca, other_cert, other_key] = common::tls_files(strangers.path());
    let stranger_client = [
        "--tls-ca",
        &ca,
        "--tls-cert",
        &other_cert,
        "--tls-key",
        &other_key,
    ];
    let trusts_another = [
        "--tls-ca",
        &other_ca,
        "--tls-cert",
        &cert,
        "--tls-key",
        &key,
    ];
    // Each is given 1 s to join (`hosts.join_timeout_s`, 5 s by default).
    let wait = ["--set", "hosts.join_timeout_s=1"];
    for tls in [stranger_client, trusts_another] {
        let three = tempfile::tempdir().unwrap();
        let out = agent.run(
            "compute",
            &["mpc"],
            three.path(),
            &[&SHORT[..], &tls, &wait].concat(),
        );
        assert_eq!(out.status.code(), Some(1), "{tls:?}: {}", stderr(&out));
        assert!(stderr(&out).contains("did not join"), "{}", stderr(&out));
    }
}
