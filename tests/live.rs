//! The live view (`scmpc run --live`, docs/foxglove.md, "Live"), watched by a client
//! written from the protocol's public specification (`common::foxglove`), while the run
//! drives in real time beside clients that misbehave.

use crate::common;

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Stdio;
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};
use study::foxglove_client::{Client, Frame};
use tungstenite::Message;

/// The token of the runs that take goals (a goal needs one, even on loopback).
const TOKEN: &str = "a-test-token-of-32-characters-00";

/// A run started with `args` (and `--out dir`), its stdout read for the live view's
/// address: the child and the URL.
fn start(dir: &std::path::Path, args: &[&str]) -> (std::process::Child, String, Receiver<String>) {
    let mut child = common::scmpc()
        .arg("run")
        .args(args)
        .arg("--out")
        .arg(dir)
        .stdout(Stdio::piped())
        .spawn()
        .expect("cannot start scmpc");
    let lines = common::lines_of(child.stdout.take().unwrap());
    let url = loop {
        let line = lines
            .recv_timeout(Duration::from_secs(30))
            .expect("the run never printed its live view's address");
        if let Some(rest) = line.strip_prefix("live view: ") {
            break rest.split(' ').next().unwrap().to_string();
        }
    };
    (child, url, lines)
}

/// A client subscribed to everything, reading until the server closes: the messages it
/// received per topic, and the last one on `/robot/truth`.
fn watch(
    url: &str,
) -> (
    BTreeMap<String, usize>,
    Vec<String>,
    Option<serde_json::Value>,
) {
    let mut client = Client::connect(url, true).expect("the watcher connects");
    let mut counts = BTreeMap::new();
    let mut last_pose = None;
    while let Ok(frame) = client.read() {
        if let Frame::Data { topic, payload, .. } = frame {
            if topic == "/robot/truth" {
                last_pose = Some(serde_json::from_slice(&payload).unwrap());
            }
            *counts.entry(topic).or_insert(0) += 1;
        }
    }
    let advertised = client.channels.values().cloned().collect();
    (counts, advertised, last_pose)
}

/// `scmpc echo estimate` on the run recording into `dir`, once the run has said where it
/// is reached (`run.json`), read as it prints: its output once it ends.
fn attach_echo(dir: &std::path::Path) -> std::thread::JoinHandle<std::process::Output> {
    let info = dir.join("run.json");
    assert!(
        common::wait_for(Duration::from_secs(30), || info.exists()),
        "no run.json"
    );
    let echo = common::scmpc()
        .args(["echo", "estimate", "--run"])
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start scmpc echo");
    std::thread::spawn(move || echo.wait_with_output().expect("echo's output"))
}

/// What `scmpc echo` printed: estimates as JSON lines, tick after tick, for the run's
/// length (it ended with the run).
fn assert_echoed_estimates(echoed: &std::process::Output) {
    let text = String::from_utf8_lossy(&echoed.stdout);
    let stderr = String::from_utf8_lossy(&echoed.stderr);
    assert!(echoed.status.success(), "echo: {stderr}");
    let ticks: Vec<u64> = (text.lines())
        .map(|l| serde_json::from_str::<serde_json::Value>(l).expect("a JSON line"))
        .map(|v| {
            assert_eq!(v["topic"], "estimate");
            assert_eq!(v["state"].as_array().map(Vec::len), Some(4), "{v}");
            v["header"]["tick"].as_u64().expect("a tick")
        })
        .collect();
    assert!(ticks.len() > 1000, "echo printed {} estimates", ticks.len());
    assert!(ticks.windows(2).all(|w| w[0] < w[1]), "ticks out of order");
}

/// `scmpc ps` lists the run in `dir`, and `scmpc topics` its estimates at the tick rate.
fn listed_by_ps_and_topics(dir: &std::path::Path) -> Result<(), String> {
    let ps = common::run(&["ps"]);
    let ps = String::from_utf8_lossy(&ps.stdout).into_owned();
    let shown = std::path::absolute(dir).unwrap();
    if !ps
        .lines()
        .any(|l| l.contains("realtime") && l.ends_with(&*shown.to_string_lossy()))
    {
        return Err(format!("`scmpc ps` lacks the run: {ps}"));
    }
    let topics = common::run(&["topics", "--run", dir.to_str().unwrap()]);
    let topics = String::from_utf8_lossy(&topics.stdout).into_owned();
    let rate = (topics.lines())
        .find(|l| l.starts_with("estimate "))
        .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok());
    match rate {
        Some(hz) if (150.0..=250.0).contains(&hz) => Ok(()),
        _ => Err(format!(
            "`scmpc topics`: no estimate at about 200 Hz: {topics}"
        )),
    }
}

/// A `geometry_msgs/PoseStamped` at `(x, y)`, heading along x, as Foxglove's publish
/// panel sends it.
fn pose_stamped(x: f64, y: f64) -> serde_json::Value {
    serde_json::json!({
        "header": { "stamp": { "sec": 0, "nsec": 0 }, "frame_id": "world" },
        "pose": {
            "position": { "x": x, "y": y, "z": 0.0 },
            "orientation": { "x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0 },
        },
    })
}

/// Sends a goal at `(x, y)` as a new client: the status the run answers with.
fn send_goal(url: &str, x: f64, y: f64) -> (u64, String) {
    send_goal_on(url, "/goal", x, y)
}

/// [`send_goal`] on `topic`.
fn send_goal_on(url: &str, topic: &str, x: f64, y: f64) -> (u64, String) {
    let mut client = Client::connect(url, false).expect("a client with a goal");
    let channel = client
        .advertise(topic, "geometry_msgs/PoseStamped")
        .unwrap();
    client.publish(channel, &pose_stamped(x, y)).unwrap();
    client
        .status(Duration::from_secs(5))
        .expect("no answer to the goal")
}

/// Time from starting to connect to the first message on `/world/obstacles` (logged once,
/// at time 0) and on `/robot/truth`.
fn late_client(url: &str) -> Duration {
    let started = Instant::now();
    let mut client = Client::connect(url, true).expect("the late client connects");
    for topic in ["/world/obstacles", "/robot/truth"] {
        let frame = client.first_on(topic, Duration::from_secs(2));
        assert!(frame.is_some(), "the late client got nothing on {topic}");
    }
    started.elapsed()
}

/// Clients of `url` (at `address`) that misbehave while the run drives: one that subscribes
/// and never reads, one that sends frames the protocol does not know and bytes that are no
/// WebSocket, one that connects and says nothing, ten at once, one that drops and
/// reconnects. Each returns what it holds open until the run ends.
fn misbehave(url: &str, address: &str) -> Vec<Box<dyn Send>> {
    let mut held: Vec<Box<dyn Send>> = Vec::new();
    held.push(Box::new(
        Client::connect(url, true).expect("a client that never reads"),
    ));
    let mut rude = Client::connect(url, false).expect("a client that sends garbage");
    for message in [
        Message::text("this is not JSON"),
        Message::text(r#"{"op":"subscribe","subscriptions":"all of them"}"#),
        Message::text(r#"{"op":"advertise","channels":[{"id":1,"topic":"/goal"}]}"#),
        Message::binary(vec![1, 1, 0, 0, 0, b'{', b'}']),
        Message::binary(vec![0xff; 64]),
    ] {
        let _ = rude.send(message);
    }
    held.push(Box::new(rude));
    let mut raw = TcpStream::connect(address).unwrap();
    raw.write_all(b"\x16\x03\x01\x00\xff not http at all\r\n\r\n")
        .unwrap();
    let mut answer = String::new();
    let _ = raw.read_to_string(&mut answer);
    assert!(answer.starts_with("HTTP/1.1 400"), "{answer}");
    held.push(Box::new(TcpStream::connect(address).unwrap()));
    let ten: Vec<Client> = (0..10)
        .map(|_| Client::connect(url, true).expect("one of ten clients"))
        .collect();
    for mut client in ten {
        assert!(
            client
                .first_on("/robot/truth", Duration::from_secs(5))
                .is_some()
        );
    }
    let dropped = Client::connect(url, true).expect("a client that will drop");
    drop(dropped);
    let mut again = Client::connect(url, true).expect("the client reconnecting");
    assert!(
        again
            .first_on("/robot/truth", Duration::from_secs(5))
            .is_some()
    );
    held
}

#[test]
fn a_live_view_serves_every_channel_of_a_real_time_run_to_the_end_whatever_its_clients_do() {
    common::until_judged(|machine| {
        let dir = tempfile::tempdir().unwrap();
        // The paper scenario, ending once the robot is held at its goal (about 17 s, not 30).
        let token = format!("live.token={TOKEN}");
        let (mut run, base, lines) = start(
            dir.path(),
            &[
                "--mode",
                "realtime",
                "--live",
                "127.0.0.1:0",
                "--set",
                "live.accept_goals=true",
                "--set",
                &token,
                "--set",
                "robot.final_approach=settle",
            ],
        );
        let url = format!("{base}/?token={TOKEN}");
        let watcher = {
            let url = url.clone();
            std::thread::spawn(move || watch(&url))
        };
        // `scmpc echo` attached for the whole run, as a ROS user would `ros2 topic echo`.
        let echo = attach_echo(dir.path());
        let held = misbehave(&url, base.trim_start_matches("ws://"));
        // A goal inside the paper's obstacle (radius 1.5 m at (3, 3.5)) is refused, and why.
        let (level, refusal) = send_goal(&url, 3.0, 3.5);
        assert_eq!(level, 2, "{refusal}");
        assert!(refusal.contains("inside obstacle 0"), "{refusal}");
        // At 10 s of the run (its first line of output says when it started): a client that
        // comes late gets the scene at once.
        let mut clock = Client::connect(&url, false).expect("a clock");
        let at_10_s = loop {
            match clock.read() {
                Ok(Frame::Time(ns)) if ns >= 10_000_000_000 => break ns,
                Ok(_) => {}
                Err(e) => panic!("the clock stopped before 10 s: {e}"),
            }
        };
        drop(clock);
        let late = late_client(&url);
        let listed = listed_by_ps_and_topics(dir.path());
        let status = run.wait().unwrap();
        drop(held);
        let (counts, advertised, last_pose) = watcher.join().unwrap();
        let echoed = echo.join().expect("echo ended");
        let stdout: Vec<String> = lines.try_iter().collect();
        assert!(status.success(), "the run failed: {status}");
        assert!(at_10_s >= 10_000_000_000);
        assert!(
            late < Duration::from_millis(200),
            "a client connecting at 10 s got the scene after {late:?}"
        );
        for topic in &advertised {
            assert!(
                counts.get(topic).is_some_and(|&n| n > 0),
                "nothing on {topic}: {counts:?}"
            );
        }
        for topic in [
            "/world/obstacles",
            "/robot/truth",
            "/mpc/plan",
            "/dfl/deadline",
            "/dfl/command",
        ] {
            assert!(
                advertised.iter().any(|t| t == topic),
                "{topic} not advertised"
            );
        }
        let last_pose = last_pose.expect("no pose");
        let trajectory = common::csv(&dir.path().join("trajectory.csv"));
        let last_row = trajectory.last().unwrap();
        let position = &last_pose["pose"]["position"];
        let dx = position["x"].as_f64().unwrap() - common::num(last_row, "x");
        let dy = position["y"].as_f64().unwrap() - common::num(last_row, "y");
        assert!(
            dx.hypot(dy) < 0.01,
            "the last pose is {dx:.4}, {dy:.4} m off the record's"
        );
        let s = common::summary(dir.path());
        assert_eq!(s["outcome"], "reached");
        // ... and the run went on to its own goal.
        assert!(
            !common::events(dir.path())
                .iter()
                .any(|e| e["event"] == "goal")
        );
        assert!(s["final_distance_to_goal_m"].as_f64().unwrap() < 0.1);
        machine.judge(&common::events(dir.path()))?;
        assert_echoed_estimates(&echoed);
        // `scmpc echo` left as the run ended, so nothing of the run is left behind.
        assert_eq!(s["leftover_files"], serde_json::json!([]), "{s}");
        assert!(listed.is_ok(), "{listed:?}");
        // Without a terminal, a progress line every 5 s of the run (about 17 s).
        let progress = (stdout.iter())
            .filter(|l| l.starts_with("t ") && l.contains("| deadline misses "))
            .count();
        assert!(
            (2..=4).contains(&progress),
            "{progress} progress lines: {stdout:?}"
        );
        // Whatever its clients do, the orchestrator stays within its bound (docs/foxglove.md):
        // every client's queue is bounded.
        let rss_kib = s["peak_rss_kib"]["orchestrator"].as_u64().unwrap();
        assert!(
            rss_kib < 64 * 1024,
            "the orchestrator peaked at {rss_kib} KiB"
        );
        eprintln!(
            "late client: {late:?}; orchestrator peak RSS {} KiB; {} topics",
            s["peak_rss_kib"]["orchestrator"],
            counts.len()
        );
        Ok(())
    })
}

#[test]
fn off_loopback_a_client_without_the_token_is_refused_before_it_sees_a_channel() {
    let _machine = common::machine_shared();
    let token = TOKEN;
    let out = common::run(&[
        "run",
        "--live",
        "0.0.0.0:0",
        "--set",
        "duration_s=1",
        "--no-mcap",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        common::stderr(&out).contains("live.token"),
        "{}",
        common::stderr(&out)
    );
    let dir = tempfile::tempdir().unwrap();
    let (mut run, url, _lines) = start(
        dir.path(),
        &[
            "--live",
            "0.0.0.0:0",
            "--live-pace",
            "--set",
            &format!("live.token={token}"),
            "--set",
            "duration_s=3",
            "--no-mcap",
        ],
    );
    let url = url.replace("0.0.0.0", "127.0.0.1");
    match Client::connect(&url, false) {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 401),
        Err(e) => panic!("refused, but not as unauthorized: {e}"),
        Ok(client) => panic!("admitted without a token, to {:?}", client.channels),
    }
    match Client::connect(
        &format!("{url}/?token=not-the-token-of-32-characters-0"),
        false,
    ) {
        Err(tungstenite::Error::Http(response)) => assert_eq!(response.status(), 401),
        other => panic!("a wrong token: {:?}", other.err()),
    }
    let mut client =
        Client::connect(&format!("{url}/?token={token}"), false).expect("with the token");
    assert!(
        client.advertised("/robot/truth", Duration::from_secs(5)),
        "{:?}",
        client.channels
    );
    // Watching is not steering: without live.accept_goals, a goal is refused.
    let (level, refusal) = send_goal(&format!("{url}/?token={token}"), 5.0, 5.0);
    assert_eq!(level, 2, "{refusal}");
    assert!(refusal.contains("live.accept_goals = false"), "{refusal}");
    // 3 s are too short to reach the goal: the run ends, recorded, not reached.
    run.wait().unwrap();
    assert_eq!(common::summary(dir.path())["outcome"], "timeout");
}

#[test]
fn a_goal_sent_from_the_viewer_mid_run_is_set_for_every_process_and_reached() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let token = format!("live.token={TOKEN}");
    let (mut run, base, _lines) = start(
        dir.path(),
        &[
            "--live",
            "127.0.0.1:0",
            "--live-pace",
            "--set",
            "live.accept_goals=true",
            "--set",
            &token,
            "--set",
            "planner.kind=route",
            "--set",
            "robot.final_approach=settle",
            "--set",
            "duration_s=20",
            "--no-mcap",
        ],
    );
    let url = format!("{base}/?token={TOKEN}");
    // (Settling, the run ends once the robot is held at its goal.) At 1 s of the run, from (7, 7) on its way to (0, 0): go to (5.5, 4.5) instead.
    let mut clock = Client::connect(&url, false).expect("a clock");
    while !matches!(clock.read(), Ok(Frame::Time(ns)) if ns >= 1_000_000_000) {}
    let (level, answer) = send_goal(&url, 5.5, 4.5);
    assert_eq!(level, 0, "{answer}");
    assert!(answer.contains("goal accepted"), "{answer}");
    let started = Instant::now();
    assert!(
        run.wait().unwrap().success(),
        "the new goal was not reached"
    );
    eprintln!(
        "the run ended {:?} after the goal was sent",
        started.elapsed()
    );
    let s = common::summary(dir.path());
    assert_eq!(s["outcome"], "reached");
    let events = common::events(dir.path());
    let goal = events
        .iter()
        .find(|e| e["event"] == "goal")
        .expect("a goal event");
    assert_eq!(
        (goal["x"].as_f64(), goal["y"].as_f64()),
        (Some(5.5), Some(4.5))
    );
    let last = common::csv(&dir.path().join("trajectory.csv"))
        .pop()
        .unwrap();
    let off = (common::num(&last, "x") - 5.5).hypot(common::num(&last, "y") - 4.5);
    assert!(
        off < 0.1,
        "the robot ended {off:.3} m from the goal it was sent"
    );
}

#[test]
fn the_foxglove_layout_names_only_channels_of_the_record() {
    let _machine = common::machine_shared();
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/docs/foxglove-layout.json");
    let layout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let panels = layout["configById"].as_object().unwrap();
    let mut named = Vec::new();
    for panel in panels.values() {
        named.extend(
            panel["topics"]
                .as_object()
                .into_iter()
                .flat_map(|t| t.keys().cloned()),
        );
        for path in panel["paths"].as_array().into_iter().flatten() {
            let value = path["value"].as_str().unwrap();
            named.push(value.split('.').next().unwrap().to_string());
        }
        named.extend(panel["topicToRender"].as_str().map(String::from));
    }
    assert!(named.len() > 10, "{named:?}");
    let channels: Vec<&str> = record::mcap::topics().collect();
    for topic in &named {
        assert!(
            channels.contains(&topic.as_str()),
            "{topic} is no channel of run.mcap"
        );
    }
    // Every panel the layout places is configured, and every configured one is placed.
    let placed = layout["layout"].to_string();
    for id in panels.keys() {
        assert!(placed.contains(&format!("\"{id}\"")), "{id} is not placed");
    }
}

#[test]
fn a_fleets_live_view_serves_every_robots_channels_under_its_id_paced_and_takes_each_robots_goal() {
    watch_a_fleet(&[]);
}

#[test]
fn a_fleet_in_one_process_is_served_live_as_across_processes() {
    watch_a_fleet(&["--in-process"]);
}

#[test]
fn a_fleet_in_real_time_is_served_live_as_in_lockstep() {
    watch_a_fleet(&["--mode", "realtime"]);
}

/// `swap4` for 3 s with a live view held to real time (`--live-pace`, or in real time)
/// that takes goals, and `mode`'s options: a goal on `/goal` names no robot and is
/// ignored, one on `/robot1/goal` is robot 1's alone; a client's clock advances at the
/// wall clock's pace (2 s of the run's time between two of its frames); every robot's
/// channels are served under its id, and only those.
fn watch_a_fleet(mode: &[&str]) {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let duration_s = 3.0;
    let duration = format!("duration_s={duration_s}");
    let token = format!("live.token={TOKEN}");
    let mut args = vec!["swap4", "--live", "127.0.0.1:0", "--live-pace"];
    args.extend(["--set", &duration, "--no-mcap"]);
    args.extend(["--set", "live.accept_goals=true", "--set", &token]);
    args.extend(mode);
    let (mut run, base, _lines) = start(dir.path(), &args);
    let url = format!("{base}/?token={TOKEN}");
    let watcher = {
        let url = url.clone();
        std::thread::spawn(move || watch(&url))
    };
    // The view's clock (the robots' truths) moves at the wall clock's pace: its frames
    // read as they come, on a thread of their own, while the goals are sent.
    let clock = {
        let mut clock = Client::connect(&url, false).expect("a clock");
        std::thread::spawn(move || {
            let mut time_at = |at_s: f64| loop {
                match clock.read() {
                    Ok(Frame::Time(ns)) if ns as f64 * 1e-9 >= at_s => {
                        break (ns, Instant::now());
                    }
                    Ok(_) => {}
                    Err(e) => panic!("the view closed before its clock reached {at_s} s: {e}"),
                }
            };
            (time_at(0.5), time_at(2.5))
        })
    };
    let (level, ignored) = send_goal(&url, 1.0, 4.0);
    assert_eq!(level, 1, "{ignored}");
    assert!(
        ignored.contains("/goal (json) is ignored")
            && ignored.contains("/robot0/goal … /robot3/goal"),
        "{ignored}"
    );
    let (level, taken) = send_goal_on(&url, "/robot1/goal", 1.0, 4.0);
    assert_eq!(level, 0, "{taken}");
    let ((first_ns, first), (last_ns, last)) = clock.join().unwrap();
    assert!(
        first_ns < 1_000_000_000,
        "the clock was first read at {first_ns} ns"
    );
    let simulated_s = (last_ns - first_ns) as f64 * 1e-9;
    let wall_s = (last - first).as_secs_f64();
    assert!(
        wall_s >= simulated_s * 0.95,
        "{simulated_s:.3} s of the run's clock in {wall_s:.3} s of wall time"
    );
    // 3 s is not enough to reach a goal: the run ends as a run short of its goals does.
    assert_eq!(run.wait().unwrap().code(), Some(1));
    let (counts, advertised, _) = watcher.join().unwrap();
    let under_an_id = |t: &String| {
        let id = t
            .strip_prefix("/robot")
            .and_then(|rest| rest.split_once('/'));
        id.is_some_and(|(id, _)| id.parse::<usize>().is_ok_and(|id| id < 4))
    };
    let stray: Vec<_> = advertised.iter().filter(|t| !under_an_id(t)).collect();
    assert!(stray.is_empty(), "channels under no robot's id: {stray:?}");
    for robot in 0..4 {
        for topic in ["/robot/truth", "/mpc/plan", "/world/obstacles"] {
            let topic = record::mcap::fleet_topic(robot, topic);
            assert!(advertised.contains(&topic), "{topic} not in {advertised:?}");
        }
        let truth = record::mcap::fleet_topic(robot, "/robot/truth");
        let seen = counts.get(&truth).copied().unwrap_or(0);
        assert!(seen > 100, "{seen} messages on {truth}: {counts:?}");
        let robot_dir = dir.path().join(format!("robot{robot}"));
        let goals: Vec<_> = (common::events(&robot_dir).into_iter())
            .filter(|e| e["event"] == "goal")
            .map(|e| (e["x"].as_f64(), e["y"].as_f64()))
            .collect();
        match robot {
            1 => assert_eq!(goals, [(Some(1.0), Some(4.0))]),
            _ => assert!(goals.is_empty(), "robot {robot}: {goals:?}"),
        }
    }
    // Robot 1 turned from its own goal, 6 m ahead, towards the one it was sent.
    let robot1 = dir.path().join("robot1");
    let last = common::csv(&robot1.join("trajectory.csv")).pop().unwrap();
    let off = (common::num(&last, "x") - 1.0).hypot(common::num(&last, "y") - 4.0);
    assert!(
        off < 2f64.sqrt() - 0.1,
        "robot 1 ended {off:.3} m from its new goal"
    );
}
