use super::*;

#[test]
fn default_is_valid_and_round_trips_through_toml() {
    let s = Scenario::default();
    s.validate("built-in").unwrap();
    let back = Scenario::from_toml(&s.to_toml(), "built-in").unwrap();
    assert_eq!(back, s);
}

#[test]
fn set_overrides_by_dotted_path_including_array_elements() {
    let s = Scenario::default()
        .with_overrides(&[
            "mpc.gamma=0.3".into(),
            "mpc.constraint=euclidean".into(),
            "obstacles.0.radius=1".into(),
            "plant.noise_variance=[0.05, 0.05, 0.01]".into(),
        ])
        .unwrap();
    assert_eq!(s.mpc.gamma, 0.3);
    assert_eq!(s.mpc.constraint, ConstraintKind::Euclidean);
    assert_eq!(s.obstacles[0].radius, 1.0);
    assert_eq!(s.plant.noise_variance.per_axis(), [0.05, 0.05, 0.01]);
}

#[test]
fn set_refuses_unknown_keys_and_bad_types_naming_the_key() {
    let e = Scenario::default()
        .with_overrides(&["mpc.gama=0.3".into()])
        .unwrap_err();
    assert_eq!(e.0[0].key, "mpc.gama");
    let e = Scenario::default()
        .with_overrides(&["mpc.horizon=abc".into()])
        .unwrap_err();
    assert_eq!(e.0[0].key, "mpc.horizon");
}

#[test]
fn an_unknown_key_names_the_key_meant_in_a_file_and_in_set() {
    let e = Scenario::default()
        .with_overrides(&["mpc.horizn=3".into()])
        .unwrap_err();
    assert_eq!(e.0[0].message, "unknown key; did you mean `mpc.horizon`?");
    let e = Scenario::from_toml("[mpc]\nhorizn = 3\n", "my.toml").unwrap_err();
    assert_eq!(e.0[0].key, "mpc.horizn");
    assert_eq!(
        e.0[0].message,
        "unknown key; did you mean `mpc.horizon`? (line 2)"
    );
}

#[test]
fn an_unknown_section_or_a_field_inside_a_value_is_named_with_the_key_meant() {
    let e =
        Scenario::from_toml("[mpc]\nhorizon = 8\n[mpcc]\ngamma = 0.2\n", "my.toml").unwrap_err();
    assert_eq!(e.0[0].key, "mpcc");
    assert!(
        e.0[0]
            .message
            .starts_with("unknown key; did you mean `mpc`"),
        "{}",
        e.0[0].message
    );
    let e = Scenario::default()
        .with_overrides(&["obstacles=[{x=1, y=2, radus=1}]".into()])
        .unwrap_err();
    assert!(
        e.0[0]
            .message
            .contains("`radus` in it: unknown key; did you mean `obstacles.<i>.radius`"),
        "{}",
        e.0[0].message
    );
}

#[test]
fn an_index_past_the_list_says_how_many_there_are() {
    let e = Scenario::default()
        .with_overrides(&["obstacles.5.radius=1".into(), "swap.0.role=mpc".into()])
        .unwrap_err();
    assert_eq!(e.0[0].message, "`obstacles` has 1 entry, `obstacles.0`");
    assert!(e.0[1].message.contains("`[[swap]]`"), "{}", e.0[1].message);
}

#[test]
fn a_value_of_the_wrong_type_is_told_what_the_key_takes_in_words() {
    let e = Scenario::default()
        .with_overrides(&["mpc.horizon=abc".into(), "dfl.brake_decel=fast".into()])
        .unwrap_err();
    assert_eq!(
        e.0[0].message,
        "bad value `abc`: expected a whole number ≥ 0"
    );
    assert_eq!(
        e.0[1].message,
        "bad value `fast`: expected \"auto\" or a number"
    );
    let e = Scenario::from_toml("[timing]\nts_s = \"x\"\n", "my.toml").unwrap_err();
    assert_eq!(e.0[0].message, "expected a number (s) (line 2)");
    let e = Scenario::from_toml("[estimator]\nkind = \"ukf\"\n", "my.toml").unwrap_err();
    assert!(
        e.0[0]
            .message
            .starts_with(r#"expected one of "ekf", "passthrough""#)
    );
}

#[test]
fn each_bad_value_is_one_error_labelled_with_its_option() {
    let e = Scenario::default()
        .with_overrides_from(
            &[
                "mpc.gamma=abc".into(),
                "mpc.gamma=0.2".into(),
                "seed=x".into(),
            ],
            "--grid mpc.gamma=abc",
        )
        .unwrap_err();
    let keys: Vec<&str> = e.0.iter().map(|e| e.key.as_str()).collect();
    assert_eq!(keys, ["mpc.gamma", "seed"]);
    assert!(e.0.iter().all(|e| e.origin == "--grid mpc.gamma=abc"));
    let e = Scenario::default()
        .with_overrides(&["plant.noise_variance=-0.1".into()])
        .unwrap()
        .validate("t")
        .unwrap_err();
    assert_eq!(e.0.len(), 1, "{e}");
    assert_eq!(e.0[0].key, "plant.noise_variance");
}

/// The keys the validator names for `s`, which it must refuse.
fn refused_keys(s: &Scenario) -> Vec<String> {
    s.validate("t")
        .unwrap_err()
        .0
        .into_iter()
        .map(|e| e.key)
        .collect()
}

#[test]
fn validation_names_every_bad_key() {
    let mut s = Scenario::default();
    s.timing.ts_s = 0.0;
    s.mpc.horizon = 0;
    s.mpc.gamma = 1.5;
    s.obstacles[0].radius = -1.0;
    s.plant.noise_variance = NoiseVariance::Uniform(f64::NAN);
    let keys = refused_keys(&s);
    for k in [
        "timing.ts_s",
        "mpc.horizon",
        "mpc.gamma",
        "obstacles.0.radius",
        "plant.noise_variance",
    ] {
        assert!(keys.iter().any(|x| x == k), "{k} not reported in {keys:?}");
    }
}

#[test]
fn a_goal_takes_an_optional_heading_that_needs_the_settling_approach() {
    let s = Scenario::default()
        .with_overrides(&["robot.goal=[1, 2, 0.5]".into()])
        .unwrap();
    assert_eq!(s.robot.goal.position, [1.0, 2.0]);
    assert_eq!(s.robot.goal.yaw_rad, Some(0.5));
    let back = Scenario::from_toml(&s.to_toml(), "t").unwrap();
    assert_eq!(back.robot.goal, s.robot.goal);
    let plain = Scenario::from_toml(&Scenario::default().to_toml(), "t").unwrap();
    assert_eq!(plain.robot.goal, Goal::at([0.0, 0.0]));
    for bad in ["robot.goal=[1]", "robot.goal=[1, 2, 3, 4]"] {
        let e = Scenario::default()
            .with_overrides(&[bad.into()])
            .unwrap_err();
        assert_eq!(e.0[0].key, "robot.goal", "{bad}");
        assert!(
            e.0[0].message.contains("[x, y, theta]"),
            "{}",
            e.0[0].message
        );
    }
    let mut paper = s.clone();
    paper.robot.final_approach = FinalApproach::Paper;
    assert_eq!(refused_keys(&paper), ["robot.goal"]);
    let mut wide = s;
    wide.robot.goal_yaw_tolerance_rad = 4.0;
    assert_eq!(refused_keys(&wide), ["robot.goal_yaw_tolerance_rad"]);
}

#[test]
fn parse_errors_name_the_dotted_key_and_line() {
    let text = "name = \"x\"\n[mpc]\nhorizon = \"eight\"\n";
    let e = Scenario::from_toml(text, "f.toml").unwrap_err();
    assert_eq!(e.0[0].key, "mpc.horizon");
    assert!(e.0[0].message.contains("line 3"), "{}", e.0[0].message);
    let text =
        "[[obstacles]]\nx = 1\ny = 1\nradius = 1\n[[obstacles]]\nx = 1\ny = 2\nradius = \"r\"\n";
    assert_eq!(
        Scenario::from_toml(text, "f.toml").unwrap_err().0[0].key,
        "obstacles.1.radius"
    );
}

#[test]
fn fault_sample_sets_take_lists_and_ranges() {
    let s = Scenario::default()
        .with_overrides(&[
            "fault.mpc_delay_ms=125".into(),
            "fault.mpc_delay_samples=\"100..=104\"".into(),
            "fault.mpc_fail_samples=[7, 9]".into(),
        ])
        .unwrap();
    let f = &s.fault;
    assert_eq!((99..=105).filter(|k| f.mpc_delay_ns(*k) > 0).count(), 5);
    assert_eq!(f.mpc_delay_ns(100), 125_000_000);
    assert!(f.mpc_fails(9) && !f.mpc_fails(8));
    assert!(
        SampleSet::Range("3..5".into()).contains(4) && !SampleSet::Range("3..5".into()).contains(5)
    );
    assert_eq!(f.describe().len(), 2);
    let mut bad = Scenario::default();
    bad.fault.mpc_fail_samples = SampleSet::Range("ten".into());
    assert_eq!(
        bad.validate("t").unwrap_err().0[0].key,
        "fault.mpc_fail_samples"
    );
}

#[test]
fn start_inside_an_obstacle_is_refused() {
    let mut s = Scenario::default();
    s.robot.start = [3.0, 3.5, 0.0];
    let e = s.validate("t").unwrap_err();
    assert!(e.0.iter().any(|e| e.key == "robot.start"));
}

#[test]
fn link_faults_are_refused_without_a_role_on_another_host() {
    let mut s = Scenario::default();
    s.fault.link_delay_ms = 60.0;
    s.fault.link_loss = 0.2;
    s.fault.link_down_s = [1.0, 2.0];
    let keys = refused_keys(&s);
    assert_eq!(
        keys,
        [
            "fault.link_delay_ms",
            "fault.link_loss",
            "fault.link_down_s"
        ]
    );
    s.hosts.mpc = "compute".into();
    s.hosts
        .endpoints
        .insert("compute".into(), "tcp/127.0.0.1:7447".into());
    assert!(s.validate("t").is_ok());
}

#[test]
fn a_goal_outside_the_position_box_is_refused() {
    let mut s = Scenario::default();
    s.robot.goal.position = [0.0, 12.0];
    let e = s.validate("t").unwrap_err();
    let goal =
        e.0.iter()
            .find(|e| e.key == "robot.goal")
            .expect("robot.goal not named");
    assert!(goal.message.contains("position box"), "{}", goal.message);
    s.mpc.position_max = [10.0, 12.5];
    assert!(s.validate("t").is_ok());
}

/// The paper with `obstacle` appended, from a TOML table.
fn with_obstacle(table: &str) -> Result<Validated, ScenarioErrors> {
    let text = format!("[[obstacles]]\nx = 3.0\ny = 3.5\nradius = 1.5\n\n[[obstacles]]\n{table}");
    Scenario::from_toml(&text, "t")?.validated("t")
}

#[test]
fn an_obstacle_moves_at_its_velocity_or_along_its_path() {
    let s = with_obstacle("x = -5.0\ny = 1.0\nradius = 0.3\nvelocity = [1.0, -0.5]").unwrap();
    let o = &s.obstacles[1];
    assert!(o.moves() && !s.obstacles[0].moves());
    assert_eq!(o.center_at(2.0), [-3.0, 0.0]);
    assert_eq!(o.velocity_at(7.0), [1.0, -0.5]);

    let s =
        with_obstacle("radius = 0.3\npath = [[1.0, 0.0, 0.0], [3.0, 2.0, 4.0], [4.0, 2.0, 4.0]]")
            .unwrap();
    let o = &s.obstacles[1];
    // Held at its first point before it (x and y are filled in from it) and at its last
    // after it; linear between.
    assert_eq!([o.x, o.y], [0.0, 0.0]);
    assert_eq!(o.center_at(-1.0), [0.0, 0.0]);
    assert_eq!(o.center_at(2.0), [1.0, 2.0]);
    assert_eq!(o.velocity_at(2.0), [1.0, 2.0]);
    assert_eq!(o.velocity_at(3.5), [0.0, 0.0]);
    assert_eq!(o.center_at(10.0), [2.0, 4.0]);
    // Written back and read again, it is the same obstacle.
    let back = Scenario::from_toml(&s.to_toml(), "t")
        .unwrap()
        .validated("t");
    assert_eq!(back.unwrap(), s);
}

#[test]
fn a_paths_change_of_velocity_at_a_point_is_spread_over_a_tenth_of_a_second() {
    // Two steps: from rest to (1, 2) m/s at t = 1, back to rest at t = 3.
    let path = [[1.0, 0.0, 0.0], [3.0, 2.0, 4.0], [4.0, 2.0, 4.0]];
    let tau = PATH_CORNER_S / 2.0;
    // At the point, half way: off the polyline by dv tau / 4, at the mean velocity.
    let (center, velocity) = path_state(&path, 3.0);
    assert!((center[0] - (2.0 - tau / 4.0)).abs() < 1e-12, "{center:?}");
    assert!(
        (center[1] - (4.0 - 2.0 * tau / 4.0)).abs() < 1e-12,
        "{center:?}"
    );
    assert_eq!(velocity, [0.5, 1.0]);
    // On the polyline before and after a turn.
    assert_eq!(path_state(&path, 1.0 - tau), ([0.0, 0.0], [0.0, 0.0]));
    assert_eq!(path_state(&path, 3.0 + 2.0 * tau), ([2.0, 4.0], [0.0, 0.0]));

    // The velocity is the centre's derivative and never jumps: it turns at |dv| / (2 tau).
    let h = 1e-5;
    let mut t = 0.9;
    while t < 3.2 {
        let (c0, v0) = path_state(&path, t);
        let (c1, v1) = path_state(&path, t + h);
        let accel = (v1[0] - v0[0]).hypot(v1[1] - v0[1]) / h;
        assert!(accel <= 5f64.sqrt() / (2.0 * tau) + 1e-6, "{accel} at {t}");
        for axis in 0..2 {
            let slope = (c1[axis] - c0[axis]) / h;
            assert!(
                (slope - 0.5 * (v0[axis] + v1[axis])).abs() < 1e-3,
                "{t} {axis}"
            );
        }
        t += 7e-4;
    }
}

#[test]
fn a_path_is_at_rest_at_its_first_point_when_the_run_starts_unless_it_starts_before() {
    // Starting 20 ms into the run, it turns over 40 ms about its first point, not 0.1 s:
    // at rest there at t = 0, at half its speed at 20 ms.
    let soon = [[0.02, 1.0, 0.0], [1.02, 2.0, 0.0]];
    assert_eq!(path_state(&soon, 0.0), ([1.0, 0.0], [0.0, 0.0]));
    assert_eq!(path_state(&soon, 0.02).1, [0.5, 0.0]);
    assert_eq!(path_state(&soon, 0.04).1, [1.0, 0.0]);
    // Starting at or before t = 0, it is moving already then, on the polyline.
    for first_s in [0.0, -0.02] {
        let before = [[first_s, 1.0, 0.0], [first_s + 1.0, 2.0, 0.0]];
        let (center, velocity) = path_state(&before, 0.0);
        assert!((center[0] - (1.0 - first_s)).abs() < 1e-12, "{center:?}");
        assert_eq!(velocity, [1.0, 0.0]);
    }
}

#[test]
fn a_path_drawn_every_tenth_of_a_second_from_a_bounded_acceleration_keeps_its_bound() {
    // Speeding up at 0.5 m/s^2 from rest at t = 2 for 1.5 s, then walking on: a person
    // stepping in as the fuzz draws one, whose points the polyline joins with jumps of
    // velocity of up to 0.05 m/s.
    let accel = 0.5;
    let walked = |t: f64| {
        let ramp = (t - 2.0).clamp(0.0, 1.5);
        0.5 * accel * ramp * ramp + accel * 1.5 * (t - 3.5).max(0.0)
    };
    let path: Vec<[f64; 3]> = std::iter::once([0.0, 0.0, 0.0])
        .chain((0..=30).map(|k| {
            let t = 2.0 + 0.1 * k as f64;
            [t, walked(t), 0.0]
        }))
        .collect();
    let h = 1e-4;
    let mut t = 1.5;
    // (Until the last point, where the path stops at once.)
    while t < 4.9 {
        let (c, v0) = path_state(&path, t);
        let v1 = path_state(&path, t + h).1;
        let turn = (v1[0] - v0[0]).hypot(v1[1] - v0[1]) / h;
        assert!(turn <= accel + 1e-6, "{turn} m/s^2 at {t} s");
        // Never farther from the motion drawn than a corner's cut, dv tau / 4.
        assert!(
            (c[0] - walked(t)).abs() <= accel * 0.1 * 0.05 / 4.0 + 1e-9,
            "{t}"
        );
        t += 3e-3;
    }
}

#[test]
fn a_bad_motion_is_refused_naming_the_obstacle_and_the_key() {
    for (table, key, says) in [
        (
            "x = 0.0\ny = 0.0\nradius = 0.3\nvelocity = [nan, 0.0]",
            "obstacles.1.velocity.0",
            "finite",
        ),
        (
            "radius = 0.3\nvelocity = [1.0, 0.0]\npath = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]",
            "obstacles.1.path",
            "not both",
        ),
        (
            "radius = 0.3\npath = [[0.0, 0.0, 0.0]]",
            "obstacles.1.path",
            "two",
        ),
        (
            "radius = 0.3\npath = [[0.0, 0.0, 0.0], [2.0, 1.0, 1.0], [2.0, 2.0, 2.0]]",
            "obstacles.1.path",
            "increase",
        ),
        (
            "radius = 0.3\npath = [[0.0, 0.0, 0.0], [inf, 1.0, 1.0]]",
            "obstacles.1.path.1.0",
            "finite",
        ),
        ("y = 0.0\nradius = 0.3", "obstacles.1.x", "missing"),
        (
            "x = 5.0\ny = 0.0\nradius = 0.3\npath = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]",
            "obstacles.1.x",
            "path's position",
        ),
    ] {
        let errors = with_obstacle(table).unwrap_err().0;
        assert!(
            errors
                .iter()
                .any(|e| e.key == key && e.message.contains(says)),
            "{table}: {errors:?}"
        );
    }
}

#[test]
fn a_tracker_runs_when_an_obstacle_moves_or_perception_tracks() {
    let has_tracker = |s: &Validated| s.roles().any(|r| r == crate::Role::Tracker);
    let paper = Scenario::default().validated("t").unwrap();
    assert!(!has_tracker(&paper));
    let moving = with_obstacle("x = -5.0\ny = 1.0\nradius = 0.3\nvelocity = [1.0, 0.0]").unwrap();
    assert!(has_tracker(&moving));
    assert_eq!(moving.known_obstacles().count(), 1);
    let tracked = paper
        .with_overrides(&["perception.kind=track".into()], "t")
        .unwrap();
    assert!(has_tracker(&tracked));
    assert_eq!(tracked.known_obstacles().count(), 0);
    // A swap or a host of a tracker that does not run is refused.
    let swap = "[[swap]]\ntime_s = 1.0\nrole = \"tracker\"\ncommand = [\"scmpc\", \"tracker\"]\n";
    let e = Scenario::from_toml(swap, "t")
        .unwrap()
        .validated("t")
        .unwrap_err();
    assert_eq!(e.0[0].key, "swap.0.role");
}

#[test]
fn with_a_lidar_the_map_is_the_known_obstacles_and_the_tracker_sees_the_others() {
    let roles = |s: &Validated| s.roles().map(|r| r.as_str()).collect::<Vec<_>>();
    let unmapped = with_obstacle("x = -5.0\ny = 1.0\nradius = 0.3\nknown = false")
        .unwrap()
        .with_overrides(&["lidar.rate_hz=20".into()], "t")
        .unwrap();
    assert!(unmapped.sees_with_lidar());
    assert!(roles(&unmapped).contains(&"lidar") && roles(&unmapped).contains(&"tracker"));
    // The paper's obstacle is the map; the one not known is nobody's but the lidar's.
    assert_eq!(unmapped.known_obstacles().count(), 1);
    assert_eq!(unmapped.tracked().count(), 0);
    // Its scans are the perception ticks: 20 Hz at the paper's 5 ms ticks.
    assert_eq!(unmapped.perception_ticks(), 10);
    // Without a lidar an obstacle at rest not known is measured from the truth.
    let blind = with_obstacle("x = -5.0\ny = 1.0\nradius = 0.3\nknown = false").unwrap();
    assert!(!blind.sees_with_lidar() && !roles(&blind).contains(&"lidar"));
    assert_eq!(blind.tracked().map(|(i, _)| i).collect::<Vec<_>>(), [1]);
}

#[test]
fn a_live_view_is_set_like_any_key_checked_and_never_written_out() {
    let token = "0123456789abcdef-_.~";
    let s = Scenario::default()
        .with_overrides(&[
            "live.address=0.0.0.0:8765".into(),
            format!("live.token={token}"),
        ])
        .unwrap();
    s.validate("t").unwrap();
    let live = s.live.as_ref().unwrap();
    assert_eq!(
        (live.address.as_str(), live.token.as_str()),
        ("0.0.0.0:8765", token)
    );
    // Neither the run directory's scenario.toml nor a role process sees the token.
    assert!(!s.to_toml().contains("live") && !s.to_toml().contains(token));
    // A later override keeps the section.
    let paced = s.with_overrides(&["live.pace=true".into()]).unwrap();
    assert_eq!(paced.live.as_ref().unwrap().token, token);
    let problem = |overrides: &[&str]| {
        let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
        let e = (Scenario::default().with_overrides(&overrides).unwrap())
            .validate("t")
            .unwrap_err();
        e.0.iter().map(|e| e.key.clone()).collect::<Vec<_>>()
    };
    assert_eq!(problem(&["live.address=0.0.0.0:8765"]), ["live.token"]);
    assert_eq!(problem(&["live.address=robot:8765"]), ["live.address"]);
    assert_eq!(problem(&["live.token=short"]), ["live.token"]);
    assert_eq!(
        problem(&["live.token=0123456789abcdef&x=1"]),
        ["live.token"]
    );
    let loopback = Scenario::default()
        .with_overrides(&["live.address=127.0.0.1:0".into()])
        .unwrap();
    loopback.validate("t").unwrap();
}
