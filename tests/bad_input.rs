//! Bad scenarios and overrides are refused before anything runs: exit code 2, and a
//! message naming the file and the key.

use crate::common;

use common::{run, stderr};

/// Writes `toml` to a scenario file, runs it, and checks the refusal.
fn refused_file(toml: &str, key: &str) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, toml).unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        file.to_str().unwrap(),
        "--in-process",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let msg = stderr(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "{toml:?} was not refused: {msg}"
    );
    assert!(
        msg.contains("bad.toml"),
        "message does not name the file: {msg}"
    );
    assert!(msg.contains(key), "message does not name `{key}`: {msg}");
    assert!(
        !out_dir.exists(),
        "a refused scenario still created its run directory"
    );
}

fn refused_set(set: &str, key: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        set,
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    let msg = stderr(&out);
    assert_eq!(
        out.status.code(),
        Some(2),
        "--set {set} was not refused: {msg}"
    );
    assert!(msg.contains(key), "message does not name `{key}`: {msg}");
    assert!(!out_dir.exists());
}

#[test]
fn unparseable_file_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc\nhorizon = 8", "bad.toml");
}

#[test]
fn unknown_key_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc]\ngama = 0.3\n", "gama");
}

#[test]
fn badly_typed_value_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc]\nhorizon = \"eight\"\n", "horizon");
}

#[test]
fn non_positive_sample_period_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[timing]\nts_s = 0.0\n", "timing.ts_s");
    refused_file("[timing]\nts_s = -0.05\n", "timing.ts_s");
}

#[test]
fn zero_horizon_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc]\nhorizon = 0\n", "mpc.horizon");
}

#[test]
fn gamma_outside_zero_one_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc]\ngamma = 0.0\n", "mpc.gamma");
    refused_file("[mpc]\ngamma = 1.5\n", "mpc.gamma");
}

#[test]
fn negative_radius_is_refused() {
    let _machine = common::machine_shared();
    refused_file(
        "[[obstacles]]\nx = 1.0\ny = 1.0\nradius = -0.5\n",
        "obstacles.0.radius",
    );
}

#[test]
fn negative_variance_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[plant]\nnoise_variance = -0.05\n", "plant.noise_variance");
}

#[test]
fn non_finite_number_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[mpc]\nv_max = nan\n", "mpc.v_max");
    refused_file("[robot]\nstart = [inf, 7.0, 0.0]\n", "robot.start.0");
}

#[test]
fn start_inside_an_obstacle_is_refused() {
    let _machine = common::machine_shared();
    refused_file("[robot]\nstart = [3.0, 3.0, 0.0]\n", "robot.start");
}

#[test]
fn constraint_horizon_and_inner_steps_out_of_range_are_refused() {
    let _machine = common::machine_shared();
    refused_file(
        "[mpc]\nconstraint_horizon = 100000\n",
        "mpc.constraint_horizon",
    );
    refused_file("[timing]\ninner_steps = 0\n", "timing.inner_steps");
}

#[test]
fn set_with_unknown_key_is_refused() {
    let _machine = common::machine_shared();
    refused_set("mpc.gama=0.3", "mpc.gama");
}

#[test]
fn set_with_badly_typed_value_is_refused() {
    let _machine = common::machine_shared();
    refused_set("mpc.horizon=abc", "mpc.horizon");
    refused_set("mpc.constraint=circle", "mpc.constraint");
}

#[test]
fn set_with_impossible_value_is_refused() {
    let _machine = common::machine_shared();
    refused_set("mpc.gamma=2", "mpc.gamma");
}

#[test]
fn missing_scenario_file_is_refused() {
    let _machine = common::machine_shared();
    let out = run(&["run", "/nonexistent/scenario.toml", "--in-process"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("/nonexistent/scenario.toml"));
}

#[test]
fn a_start_within_the_robots_radius_of_an_obstacle_is_refused() {
    let _machine = common::machine_shared();
    // 0.2 m from the paper's obstacle's edge, with a robot 0.3 m in radius.
    refused_file(
        "[robot]\nstart = [3.0, 5.2, 0.0]\nradius_m = 0.3\n",
        "robot.start",
    );
    refused_set("robot.radius_m=-0.1", "robot.radius_m");
}

#[test]
fn a_start_whose_braking_path_enters_an_obstacle_is_refused() {
    let _machine = common::machine_shared();
    // 1 m from the obstacle's edge, heading at it at 3 m/s: braking at 3 m/s^2 takes 1.5 m.
    refused_file(
        "[robot]\nstart = [3.0, 6.0, -1.5707963267948966]\nzeta0 = 3.0\n",
        "robot.zeta0",
    );
}

#[test]
fn a_goal_inside_an_obstacle_is_refused() {
    let _machine = common::machine_shared();
    refused_set("robot.goal=[3.0, 3.0]", "robot.goal");
}

#[test]
fn a_brake_the_input_box_cannot_deliver_is_refused_and_auto_follows_the_box() {
    let _machine = common::machine_shared();
    refused_set("dfl.brake_decel=4", "dfl.brake_decel");
    refused_set("dfl.brake_decel=fast", "dfl.brake_decel");
    refused_file(
        "[mpc]\nv_max = 1.0\n[dfl]\nbrake_decel = 2.0\n",
        "dfl.brake_decel",
    );
    // The default brake is the box's: a smaller box alone stays valid.
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        "mpc.v_max=1",
        "--set",
        "duration_s=0.5",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_ne!(out.status.code(), Some(2), "{}", stderr(&out));
    let written = std::fs::read_to_string(dir.path().join("scenario.toml")).unwrap();
    assert!(written.contains("brake_decel = \"auto\""), "{written}");
}

#[test]
fn unknown_safety_settings_are_refused() {
    let _machine = common::machine_shared();
    refused_set("mpc.terminal_safety=sometimes", "mpc.terminal_safety");
    refused_set("dfl.gatekeeper=maybe", "dfl.gatekeeper");
}

#[test]
fn a_start_outside_the_position_box_is_refused() {
    let _machine = common::machine_shared();
    refused_file(
        "[robot]\nstart = [-5.0, 7.0, 0.0]\n\n[mpc]\nposition_min = [0.0, 0.0]\n",
        "robot.start",
    );
}

#[test]
fn a_goal_outside_the_position_box_is_refused() {
    let _machine = common::machine_shared();
    refused_set("robot.goal=[0.0, 12.0]", "robot.goal");
}

#[test]
fn horizon_and_inner_steps_above_their_maxima_are_refused() {
    let _machine = common::machine_shared();
    refused_set(
        &format!("mpc.horizon={}", protocol::MAX_HORIZON + 1),
        "mpc.horizon",
    );
    refused_set(
        &format!("timing.inner_steps={}", protocol::MAX_INNER_STEPS + 1),
        "timing.inner_steps",
    );
}

#[test]
fn a_duration_of_zero_or_less_is_refused() {
    let _machine = common::machine_shared();
    refused_set("duration_s=0", "duration_s");
    refused_set("duration_s=-1", "duration_s");
}

#[test]
fn an_extra_role_that_is_no_optional_role_is_refused_naming_its_place() {
    let _machine = common::machine_shared();
    refused_set(r#"extra_roles=["mpc"]"#, "extra_roles[0]");
    refused_set(r#"extra_roles=["nobody"]"#, "`nobody` is no optional role");
}

#[test]
fn bad_planner_settings_are_refused() {
    let _machine = common::machine_shared();
    refused_set("planner.kind=astar", "planner.kind");
    refused_set("planner.period_s=-1", "planner.period_s");
    refused_set("planner.clearance_m=-0.1", "planner.clearance_m");
    refused_set("planner.speed_m_s=0", "planner.speed_m_s");
    refused_set("planner.stray_m=0", "planner.stray_m");
    refused_set("planner.switch_margin=1", "planner.switch_margin");
    refused_file(
        "[planner]\nkind = \"route\"\n[mpc]\nformulation = \"nonlinear\"\nterminal_safety = \"none\"\n",
        "planner.kind",
    );
}

/// The processes started for the run with iceoryx2 prefix `prefix` (their environment
/// names it).
fn processes_of_run(prefix: &str) -> Vec<u32> {
    let wanted = format!("SCMPC_PREFIX={prefix}");
    std::fs::read_dir("/proc")
        .unwrap()
        .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| {
            std::fs::read(format!("/proc/{pid}/environ"))
                .is_ok_and(|env| env.split(|b| *b == 0).any(|v| v == wanted.as_bytes()))
        })
        .collect()
}

/// `command` must be refused: exit 2, the message naming `names`, no run directory at
/// `out`, no process of the run `prefix` left and no shared-memory file of it. Returns what
/// is wrong, if anything.
fn refusal_problem(
    mut command: std::process::Command,
    out: &std::path::Path,
    prefix: &str,
    names: &str,
) -> Option<String> {
    let output = command.output().expect("cannot start scmpc");
    let msg = stderr(&output);
    let problem = if output.status.code() != Some(2) {
        format!("exit {:?}", output.status.code())
    } else if !msg.contains(names) {
        "the message does not name it".to_string()
    } else if out.exists() {
        "a run directory was made".to_string()
    } else if !common::leftovers(prefix).is_empty() {
        format!("files left: {:?}", common::leftovers(prefix))
    } else if !processes_of_run(prefix).is_empty() {
        format!("processes left: {:?}", processes_of_run(prefix))
    } else {
        return None;
    };
    Some(format!("{problem}: {}", msg.trim_end()))
}

/// Every key the validator checks, and every guard of the command line, with a bad value:
/// refused before anything starts (multi-process runs, so a half-started run would show).
#[test]
fn every_scenario_key_and_command_line_guard_refuses_a_bad_value_and_starts_nothing() {
    let _machine = common::machine_shared();
    // (--set values, the key the message must name)
    let sets: &[(&[&str], &str)] = &[
        (&["duration_s=0"], "duration_s"),
        (&["seed=-1"], "seed"),
        (&["timing.ts_s=-0.05"], "timing.ts_s"),
        (&["timing.inner_steps=0"], "timing.inner_steps"),
        (&["robot.start=[nan, 7.0, 0.0]"], "robot.start"),
        (&["robot.zeta0=inf"], "robot.zeta0"),
        (&["robot.goal=[inf, 0.0]"], "robot.goal"),
        (&["robot.goal_tolerance_m=0"], "robot.goal_tolerance_m"),
        (&["robot.radius_m=-0.1"], "robot.radius_m"),
        (&["plant.wheel_radius_m=0"], "plant.wheel_radius_m"),
        (&["plant.wheel_base_m=-0.5"], "plant.wheel_base_m"),
        (
            &["plant.max_wheel_speed_rad_s=-1"],
            "plant.max_wheel_speed_rad_s",
        ),
        (
            &["plant.noise_variance=[0.0, -1.0, 0.0]"],
            "plant.noise_variance",
        ),
        (&["plant.disturbance_std=-0.01"], "plant.disturbance_std"),
        (&["plant.rk4_substeps=0"], "plant.rk4_substeps"),
        (
            &["plant.command_timeout_s=0.001"],
            "plant.command_timeout_s",
        ),
        (&["estimator.kind=kalman"], "estimator.kind"),
        (
            &["estimator.process_noise=[0.0, -1.0, 0.0]"],
            "estimator.process_noise",
        ),
        (
            &["estimator.initial_variance=[-1.0, 0.0, 0.0]"],
            "estimator.initial_variance",
        ),
        (&["mpc.formulation=quadratic"], "mpc.formulation"),
        (&["mpc.qp_form=dense"], "mpc.qp_form"),
        (&["mpc.horizon=0"], "mpc.horizon"),
        (&["mpc.constraint_horizon=100000"], "mpc.constraint_horizon"),
        (&["mpc.gamma=0"], "mpc.gamma"),
        (&["mpc.constraint=circle"], "mpc.constraint"),
        (&["mpc.q_diag=[1.0, -1.0, 1.0, 1.0]"], "mpc.q_diag"),
        (&["mpc.r_diag=[100.0, 0.0]"], "mpc.r_diag.1"),
        (&["mpc.v_max=0"], "mpc.v_max"),
        (&["mpc.position_min=[10.0, -10.0]"], "mpc.position_min"),
        (&["mpc.position_max=[nan, 10.0]"], "mpc.position_max"),
        (&["mpc.safety_margin_m=-0.1"], "mpc.safety_margin_m"),
        (&["mpc.uncertainty_sigmas=-1"], "mpc.uncertainty_sigmas"),
        (&["mpc.max_solves=0"], "mpc.max_solves"),
        (&["mpc.refinement_tol_m=0"], "mpc.refinement_tol_m"),
        (&["mpc.rest_lookahead_s=-0.5"], "mpc.rest_lookahead_s"),
        (&["mpc.terminal_safety=wall"], "mpc.terminal_safety"),
        (&["mpc.formulation=nonlinear"], "mpc.terminal_safety"),
        (&["dfl.zeta_threshold=-0.01"], "dfl.zeta_threshold"),
        (&["dfl.brake_decel=0"], "dfl.brake_decel"),
        (&["dfl.brake_decel=-1"], "dfl.brake_decel"),
        (&["dfl.gatekeeper=maybe"], "dfl.gatekeeper"),
        (&["planner.kind=astar"], "planner.kind"),
        (&["planner.period_s=-1"], "planner.period_s"),
        (&["planner.clearance_m=-0.1"], "planner.clearance_m"),
        (&["planner.speed_m_s=0"], "planner.speed_m_s"),
        (&["planner.stray_m=0"], "planner.stray_m"),
        (&["planner.switch_margin=-0.1"], "planner.switch_margin"),
        (&["robot.goal=[1, 2, 3, 4]"], "robot.goal"),
        (
            &["robot.goal_yaw_tolerance_rad=0"],
            "robot.goal_yaw_tolerance_rad",
        ),
        (&["robot.final_approach=dock"], "robot.final_approach"),
        (&["mpc.approach_r_diag=[0, 1]"], "mpc.approach_r_diag.0"),
        (&["obstacles.0.x=nan"], "obstacles.0.x"),
        (&["obstacles.0.y=inf"], "obstacles.0.y"),
        (&["obstacles.0.radius=-1"], "obstacles.0.radius"),
        (&["obstacles.0.known=\"maybe\""], "obstacles.0.known"),
        (&["lidar.beams=0"], "lidar.beams"),
        (&["lidar.dropout=1.5"], "lidar.dropout"),
        (&["lidar.range_max_m=0.05"], "lidar.range_max_m"),
        (&["perception.kind=\"lidar\""], "perception.kind"),
        (&["perception.confirm=9"], "perception.confirm"),
        (&["fault.mpc_delay_ms=-5"], "fault.mpc_delay_ms"),
        (&["fault.estimator_delay_ms=-5"], "fault.estimator_delay_ms"),
        (
            &["fault.estimator_nan_from_s=-1"],
            "fault.estimator_nan_from_s",
        ),
        (
            &["fault.mpc_delay_samples=\"ten\""],
            "fault.mpc_delay_samples",
        ),
        (
            &["fault.mpc_fail_samples=\"5..\""],
            "fault.mpc_fail_samples",
        ),
        (&["fault.link_delay_ms=-1"], "fault.link_delay_ms"),
        (&["fault.link_delay_ms=5"], "fault.link_delay_ms"),
        (&["fault.link_loss=1"], "fault.link_loss"),
        (&["fault.link_down_s=[5.0, 1.0]"], "fault.link_down_s"),
        (&["hosts.mpc=\"box 1\""], "hosts.mpc"),
        (&["hosts.endpoints.box=nowhere"], "hosts.endpoints.box"),
        (&["hosts.planner=box"], "hosts.planner"),
        (&["hosts.join_timeout_s=0"], "hosts.join_timeout_s"),
        (&["supervision.restart=sometimes"], "supervision.restart"),
        (&["supervision.max_restarts=-1"], "supervision.max_restarts"),
        (&["supervision.failover=remote"], "supervision.failover"),
        (&["plant.kind=robot"], "plant.kind"),
        // A ROS 2 robot in lockstep (the default mode).
        (&["plant.kind=ros2"], "plant.kind"),
        (&["ros2.endpoint=udp/127.0.0.1:7447"], "ros2.endpoint"),
        (&["ros2.endpoint=tcp/127.0.0.1"], "ros2.endpoint"),
        (&["ros2.domain_id=233"], "ros2.domain_id"),
        (&["ros2.namespace=\"robot 1\""], "ros2.namespace"),
        (&["ros2.node=scmpc-1"], "ros2.node"),
        (&["ros2.distro=humble"], "ros2.distro"),
        (&["ros2.wire=dds"], "ros2.wire"),
        (&["ros2.cmd_vel=cmd-vel"], "ros2.cmd_vel"),
        (&["ros2.odom=\"\""], "ros2.odom"),
        (&["ros2.goal_topic=1goal"], "ros2.goal_topic"),
        (&["ros2.odom_timeout_s=0"], "ros2.odom_timeout_s"),
        (
            &["ros2.first_message_timeout_s=-1"],
            "ros2.first_message_timeout_s",
        ),
        (&["realtime.priority=3"], "realtime.priority"),
        (&["realtime.priority=fifo"], "realtime.priority"),
        (&["realtime.cpus=[0, 0]"], "realtime.cpus"),
    ];
    // (a scenario file, the key)
    let files: &[(&str, &str)] = &[
        (
            "[[swap]]\ntime_s = 40.0\nrole = \"estimator\"\ncommand = []\n",
            "swap.0.time_s",
        ),
        (
            "[[swap]]\ntime_s = 5.0\nrole = \"plant\"\ncommand = []\n",
            "swap.0.role",
        ),
        (
            "[[swap]]\ntime_s = 5.0\nrole = \"estimator\"\ncommand = [\" \"]\n",
            "swap.0.command",
        ),
    ];
    // (the command line, what the message must name)
    let guards: &[(&[&str], &str)] = &[
        (
            &["run", "--in-process", "--mode", "realtime"],
            "--in-process",
        ),
        (&["run", "--keep-cores-awake"], "--keep-cores-awake"),
        (&["run", "--prefix", "a/b"], "--prefix"),
        (&["run", "--host", "mpc"], "--host mpc"),
        (&["scenario", "nowhere"], "no built-in scenario `nowhere`"),
        (&["bench", "--realtime-s", "0"], "--realtime-s"),
        (&["bench", "--realtime-s=-1"], "--realtime-s"),
        (&["bench", "--load", "0"], "--load"),
        (
            &["run", "--mode", "realtime", "--set", "realtime.cpus=[1023]"],
            "realtime.cpus: CPU 1023",
        ),
        (&["fuzz", "--mcap"], "--mcap"),
        (&["fuzz", "--people", "1.5"], "--people"),
        (&["sweep", "--grid", "mpc.gama=0.1,0.2"], "mpc.gama"),
        (
            &[
                "host",
                "--name",
                "orchestrator",
                "--listen",
                "tcp/127.0.0.1:0",
            ],
            "--name",
        ),
        (
            &["host", "--name", "h", "--listen", "udp/127.0.0.1:0"],
            "--listen",
        ),
        (&["swap", "--run", ".", "plant"], "plant"),
        (
            &["run", "--in-process", "--set", "plant.kind=ros2"],
            "plant.kind",
        ),
        (
            &[
                "run",
                "--mode",
                "realtime",
                "--set",
                "plant.kind=ros2",
                "--set",
                "ros2.endpoint=tcp/10.0.0.7:7447",
            ],
            "ros2.endpoint",
        ),
        (&["sweep", "--set", "plant.kind=ros2"], "plant.kind"),
        (&["fuzz", "--set", "plant.kind=ros2"], "plant.kind"),
    ];
    let dir = tempfile::tempdir().unwrap();
    let mut problems = Vec::new();
    let mut case = 0;
    let mut next_case = || {
        case += 1;
        (
            dir.path().join(format!("run-{case}")),
            common::unique_prefix("bad"),
        )
    };
    for (values, key) in sets {
        let (out, prefix) = next_case();
        let mut command = common::scmpc();
        command
            .args(["run", "--prefix", &prefix, "--out"])
            .arg(&out);
        for value in *values {
            command.args(["--set", value]);
        }
        if let Some(p) = refusal_problem(command, &out, &prefix, key) {
            problems.push(format!("--set {values:?}: {p}"));
        }
    }
    for (toml, key) in files {
        let (out, prefix) = next_case();
        let file = out.with_extension("toml");
        std::fs::write(&file, toml).unwrap();
        let mut command = common::scmpc();
        command
            .args(["run", "--prefix", &prefix, "--out"])
            .arg(&out)
            .arg(&file);
        if let Some(p) = refusal_problem(command, &out, &prefix, key) {
            problems.push(format!("file {toml:?}: {p}"));
        }
    }
    for (args, names) in guards {
        let (out, prefix) = next_case();
        let mut command = common::scmpc();
        command.args(*args);
        // Where the command would write or open something, it is told where, so that
        // "nothing started" is checked there.
        match args[0] {
            "run" => {
                if !args.contains(&"--prefix") {
                    command.args(["--prefix", &prefix]);
                }
                command.arg("--out").arg(&out);
            }
            "sweep" | "fuzz" | "bench" => {
                command.arg("--out").arg(&out);
            }
            _ => {}
        }
        if let Some(p) = refusal_problem(command, &out, &prefix, names) {
            problems.push(format!("{args:?}: {p}"));
        }
    }
    // The role processes' own guards (the orchestrator starts them with its environment).
    let scenario = dir.path().join("scenario.toml");
    std::fs::write(&scenario, "").unwrap();
    /// (role, arguments, environment, what the message must name)
    type RoleGuard<'a> = (&'a str, &'a [&'a str], &'a [(&'a str, &'a str)], &'a str);
    let role_guards: &[RoleGuard] = &[
        ("mpc", &[], &[("SCMPC_ROLE", "estimator")], "SCMPC_ROLE"),
        ("mpc", &["--set", "timing.ts_s=0.1"], &[], "timing.*"),
        (
            "dfl",
            &["--control-publisher", "xyz"],
            &[],
            "--control-publisher",
        ),
        (
            "plant",
            &["--set", "plant.rk4_substeps=0"],
            &[],
            "plant.rk4_substeps",
        ),
    ];
    for (role, args, env, names) in role_guards {
        let (out, prefix) = next_case();
        let mut command = common::scmpc();
        command
            .args([role, "--prefix", &prefix, "--scenario"])
            .arg(&scenario)
            .args(*args)
            .envs(env.iter().copied());
        if let Some(p) = refusal_problem(command, &out, &prefix, names) {
            problems.push(format!("{role} {args:?} {env:?}: {p}"));
        }
    }
    assert!(
        problems.is_empty(),
        "not refused as they should be:\n{}",
        problems.join("\n")
    );
}

#[test]
fn a_file_or_directory_named_like_a_built_in_does_not_shadow_it_and_a_name_of_neither_names_both() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    // A directory `paper` and a broken file `field` where the user works.
    std::fs::create_dir(dir.path().join("paper")).unwrap();
    std::fs::write(dir.path().join("field"), "not = [toml").unwrap();
    std::fs::write(dir.path().join("mine"), "").unwrap();
    let in_dir = |args: &[&str]| {
        common::scmpc()
            .args(args)
            .current_dir(dir.path())
            .output()
            .unwrap()
    };
    for name in ["paper", "field"] {
        let out = in_dir(&[
            "run",
            name,
            "--in-process",
            "--no-mcap",
            "--set",
            "duration_s=0.5",
            "--out",
            &format!("run-{name}"),
        ]);
        assert_ne!(out.status.code(), Some(2), "{name}: {}", stderr(&out));
        let summary = common::summary(&dir.path().join(format!("run-{name}")));
        assert_eq!(summary["scenario"], name);
    }
    // A name that is no built-in: both ways to name a scenario, and the file that is there.
    let out = in_dir(&["run", "mine", "--in-process"]);
    let msg = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{msg}");
    assert!(
        msg.contains("not a built-in scenario (paper, paper-noisy, field, crossing")
            && msg.contains("`./mine`"),
        "{msg}"
    );
    // A path that is no file: the built-ins are named too.
    let out = in_dir(&["run", "./nosuch.toml", "--in-process"]);
    let msg = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{msg}");
    assert!(
        msg.contains("./nosuch.toml: cannot read the scenario file")
            && msg.contains("a built-in scenario is named without a path separator or `.toml`"),
        "{msg}"
    );
}

/// A user's mistakes in `--set`, each told what to do: the key meant, how many entries a
/// list has, what a key takes in words; one error per bad value, all of them at once.
#[test]
fn each_bad_override_is_one_error_that_says_what_to_do() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        "mpc.horizn=3",
        "--set",
        "obstacles.5.radius=1",
        "--set",
        "mpc.gamma=abc",
        "--set",
        "plant.noise_variance=-0.1",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let msg = stderr(&out);
    let lines: Vec<&str> = msg.lines().skip(1).collect();
    assert_eq!(
        lines,
        [
            "  --set: `mpc.horizn`: unknown key; did you mean `mpc.horizon`?",
            "  --set: `obstacles.5.radius`: `obstacles` has 1 entry, `obstacles.0`",
            "  --set: `mpc.gamma`: bad value `abc`: expected a number",
        ],
        "{msg}"
    );
    assert!(!out_dir.exists());
    // A value the validator refuses is one error, however many axes it stands for.
    let out = run(&["run", "--in-process", "--set", "plant.noise_variance=-0.1"]);
    assert_eq!(
        stderr(&out).matches("must not be negative").count(),
        1,
        "{}",
        stderr(&out)
    );
}

/// A mistyped key in a file gets the same suggestion, with its line; an unknown word the
/// key's choices.
#[test]
fn a_mistyped_key_or_word_in_a_file_is_told_the_key_or_words_meant() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("robot.toml");
    std::fs::write(&file, "[mpc]\nhorizon = 8\nconstrant = \"cbf\"\n").unwrap();
    let out = run(&["run", "--in-process", file.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(
        stderr(&out)
            .contains("`mpc.constrant`: unknown key; did you mean `mpc.constraint`? (line 3)"),
        "{}",
        stderr(&out)
    );
    std::fs::write(&file, "[estimator]\nkind = \"ukf\"\n").unwrap();
    let out = run(&["run", "--in-process", file.to_str().unwrap()]);
    assert!(
        stderr(&out).contains(r#"`estimator.kind`: expected one of "ekf", "passthrough" (line 2)"#),
        "{}",
        stderr(&out)
    );
}

/// `sweep --grid` errors are labelled with the grid value, not `--set`.
#[test]
fn a_bad_grid_value_is_labelled_with_its_grid() {
    let _machine = common::machine_shared();
    let out = run(&["sweep", "--grid", "mpc.gamma=0.1,abc"]);
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    let msg = stderr(&out);
    assert!(
        msg.contains("--grid mpc.gamma=abc: `mpc.gamma`: bad value `abc`: expected a number"),
        "{msg}"
    );
    assert!(!msg.contains("--set"), "{msg}");
}

/// `run --help` and `sweep --help` name every built-in scenario.
#[test]
fn the_help_of_run_and_sweep_names_every_built_in_scenario() {
    let _machine = common::machine_shared();
    let scenarios = run(&["scenario", "--help"]);
    for command in ["run", "sweep"] {
        let help = String::from_utf8_lossy(&run(&[command, "--help"]).stdout).into_owned();
        for name in run::scenarios::BUILT_IN.iter().map(|(n, _)| *n) {
            assert!(
                help.contains(name),
                "`{command} --help` lacks `{name}`: {help}"
            );
            assert!(String::from_utf8_lossy(&scenarios.stdout).contains(name));
        }
    }
}

/// `scmpc keys` lists every key a finished run's `scenario.toml` holds, and no key that no
/// scenario can hold; `scmpc keys TEXT` filters.
#[test]
fn scmpc_keys_lists_every_key_of_a_finished_runs_scenario() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("run");
    // A lidar's world, so that the optional `[lidar]` is written out too.
    let out = run(&[
        "run",
        "occluded",
        "--in-process",
        "--set",
        "duration_s=0.2",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(out_dir.join("scenario.toml").exists(), "{}", stderr(&out));
    let written: toml::Table = std::fs::read_to_string(out_dir.join("scenario.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let mut in_file = std::collections::BTreeSet::new();
    dotted_keys(&toml::Value::Table(written), "", &mut in_file);
    let listing = run(&["keys"]);
    assert_eq!(listing.status.code(), Some(0));
    let listed: std::collections::BTreeSet<String> = String::from_utf8_lossy(&listing.stdout)
        .lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .collect();
    // (An empty list of tables, `swap = []`, is written as a key of its own.)
    let list_of_tables = |key: &str| listed.iter().any(|l| l.starts_with(&format!("{key}.<i>.")));
    let missing: Vec<&String> = (in_file.difference(&listed))
        .filter(|k| !list_of_tables(k))
        .collect();
    assert!(missing.is_empty(), "not listed: {missing:?}");
    // What the file lacks: keys a document leaves out while empty or unset, and `[live]`,
    // which is never written.
    let absent_by_design = |key: &str| {
        key.starts_with("live.")
            || key.starts_with("swap.<i>.")
            || key.starts_with("robots.<i>.")
            || [
                "extra_roles",
                "obstacles.<i>.known",
                "hosts.endpoints.<name>",
            ]
            .contains(&key)
    };
    let extra: Vec<&String> = (listed.difference(&in_file))
        .filter(|k| !absent_by_design(k))
        .collect();
    assert!(
        extra.is_empty(),
        "listed, not in a run's scenario.toml: {extra:?}"
    );
    let ros2 = String::from_utf8_lossy(&run(&["keys", "ros2"]).stdout).into_owned();
    let rows: Vec<&str> = ros2.lines().skip(1).collect();
    assert!(
        rows.len() > 10 && rows.iter().all(|l| l.starts_with("ros2.")),
        "{ros2}"
    );
    assert!(
        ros2.contains("ros2.domain_id") && ros2.contains("a whole number ≥ 0"),
        "{ros2}"
    );
}

/// The dotted keys of a TOML document, list elements as `<i>` and names as `<name>`.
fn dotted_keys(value: &toml::Value, prefix: &str, keys: &mut std::collections::BTreeSet<String>) {
    let join = |name: &str| {
        if prefix.is_empty() {
            name.to_string()
        } else {
            format!("{prefix}.{name}")
        }
    };
    match value {
        toml::Value::Table(table) if prefix == "hosts.endpoints" => {
            if !table.is_empty() {
                keys.insert(join("<name>"));
            }
        }
        toml::Value::Table(table) => {
            for (name, value) in table {
                dotted_keys(value, &join(name), keys);
            }
        }
        toml::Value::Array(items) if items.first().is_some_and(toml::Value::is_table) => {
            for item in items {
                dotted_keys(item, &join("<i>"), keys);
            }
        }
        _ => {
            keys.insert(prefix.to_string());
        }
    }
}

/// docs/running.md's table of scenario keys names every key `scmpc keys` lists: by its
/// dotted name, as a key of a row of its `[section]` (`[[obstacles]]` `radius`), or as
/// `section.*`.
#[test]
fn the_key_table_of_the_docs_names_every_key() {
    let _machine = common::machine_shared();
    let docs =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/docs/running.md")).unwrap();
    let table = docs
        .split("## Scenario keys")
        .nth(1)
        .and_then(|rest| rest.split("\n## ").next())
        .expect("docs/running.md has a section \"Scenario keys\"");
    let first_cells: Vec<&str> = (table.lines())
        .filter_map(|l| l.strip_prefix("| ")?.split(" |").next())
        .collect();
    let named = |key: &str| {
        let parts: Vec<&str> = key.split('.').filter(|p| !p.starts_with('<')).collect();
        let (section, leaf) = (parts[..parts.len() - 1].join("."), parts[parts.len() - 1]);
        first_cells.iter().any(|cell| {
            let in_section =
                cell.contains(&format!("[{section}]")) || cell.contains(&format!("[[{section}]]"));
            cell.contains(&format!("`{key}`"))
                || cell.contains(&format!("`{}`", parts.join(".")))
                || cell.contains(&format!("`{section}.*`"))
                || cell.contains(&format!("[{}]", parts.join(".")))
                || (in_section && (cell.contains(&format!("`{leaf}`")) || key.ends_with("<name>")))
        })
    };
    let unnamed: Vec<String> = (protocol::scenario::keys::catalogue().into_iter())
        .map(|k| k.key)
        .filter(|k| !named(k))
        .collect();
    assert!(
        unnamed.is_empty(),
        "docs/running.md's key table lacks {unnamed:?}"
    );
}
