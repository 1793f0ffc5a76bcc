use super::*;
use protocol::task::Context;
use protocol::{PLAN_MISSING, PlanStatus};

#[test]
fn phi_and_its_inverse_round_trip() {
    for x_bar in [
        [1.0, -2.0, 0.3, 0.8],
        [0.0, 4.0, -2.9, 1.5],
        [-3.0, 0.5, 3.1, 0.01],
    ] {
        let back = phi_inverse(phi(x_bar), 0.0);
        for i in 0..4 {
            assert!((back[i] - x_bar[i]).abs() < 1e-12, "{x_bar:?} -> {back:?}");
        }
    }
    let at_rest = phi_inverse(phi([2.0, 3.0, 1.2, 0.0]), 1.2);
    assert_eq!(at_rest, [2.0, 3.0, 1.2, 0.0]);
}

#[test]
fn zeta_guard_zeroes_steering_below_threshold_in_both_directions() {
    // v within 45 degrees of the robot's axis (forwards, then backwards).
    for v in [[1.0, 0.5], [-1.0, -0.5]] {
        for zeta in [0.0, 0.005, -0.01, 0.01] {
            let (u, guarded) = linearizing_input(0.7, zeta, v, 0.01);
            assert!(guarded && u[1] == 0.0, "zeta {zeta}: {u:?}");
        }
    }
    let (u, guarded) = linearizing_input(0.7, -0.5, [1.0, -2.0], 0.01);
    assert!(!guarded && u[1] != 0.0);
}

#[test]
fn under_the_guard_a_plan_across_the_axis_turns_the_robot_in_place_towards_it() {
    let theta = 0.7;
    for v in [[1.0, -2.0], [-1.5, 1.0], [0.0, 1.0]] {
        let ([u1, u2], guarded) = linearizing_input(theta, 0.0, v, 0.01);
        assert!(guarded);
        // Turning at u2 for TURN_IN_PLACE_S puts v on the robot's axis.
        let aligned = theta + u2 * TURN_IN_PLACE_S;
        let across = -v[0] * aligned.sin() + v[1] * aligned.cos();
        assert!(across.abs() < 1e-12, "{v:?}: {across}");
        assert!(u2.abs() <= std::f64::consts::FRAC_PI_2 / TURN_IN_PLACE_S);
        assert_eq!(u1, v[0] * theta.cos() + v[1] * theta.sin());
    }
    // No turning for a plan that asks for (almost) nothing.
    let (u, _) = linearizing_input(theta, 0.0, [0.0, 1e-4], 0.01);
    assert_eq!(u[1], 0.0);
}

#[test]
fn z_follows_the_double_integrator_under_the_linearizing_law() {
    // Continuous DFL with constant v: z1'' = v1 and z3'' = v2 exactly, so after T
    // seconds z matches the double integrator up to RK4's error.
    let v = [0.4, -0.7];
    let x0 = [1.0, 2.0, 0.5, 1.2];
    let (t, steps) = (1.0, 1000);
    let mut x = x0;
    for _ in 0..steps {
        x = plant::rk4_step(&x, t / steps as f64, |s| extended_dynamics(s, v, 0.01));
    }
    let z0 = phi(x0);
    let expected = [
        z0[0] + z0[1] * t + 0.5 * v[0] * t * t,
        z0[1] + v[0] * t,
        z0[2] + z0[3] * t + 0.5 * v[1] * t * t,
        z0[3] + v[1] * t,
    ];
    let z = phi(x);
    for i in 0..4 {
        assert!(
            (z[i] - expected[i]).abs() < 1e-9,
            "z{i}: {} vs {}",
            z[i],
            expected[i]
        );
    }
}

#[test]
fn the_mid_tick_law_follows_the_double_integrator_ten_times_closer() {
    // A second of hard turning (about 1.7 rad/s) in 10 ms ticks, the commands held over
    // each tick as the plant holds them: u1 the mean of zeta, u2 = U2.
    let (dt, ticks, v) = (0.01, 100, [0.8, -1.5]);
    let x0 = [0.0, 0.0, 0.3, 1.0];
    let z0 = phi(x0);
    let t = dt * f64::from(ticks);
    let expected = [
        z0[0] + z0[1] * t + 0.5 * v[0] * t * t,
        z0[1] + v[0] * t,
        z0[2] + z0[3] * t + 0.5 * v[1] * t * t,
        z0[3] + v[1] * t,
    ];
    let error = |mid_tick: bool| {
        let (mut pose, mut zeta) = ([x0[0], x0[1], x0[2]], x0[3]);
        for _ in 0..ticks {
            let (u, _) = if mid_tick {
                mid_tick_linearizing_input(pose[2], zeta, v, 0.01, dt)
            } else {
                linearizing_input(pose[2], zeta, v, 0.01)
            };
            let u1 = zeta + 0.5 * u[0] * dt;
            zeta += u[0] * dt;
            for _ in 0..20 {
                pose = plant::rk4_step(&pose, dt / 20.0, |x| plant::unicycle(x, u1, u[1]));
            }
        }
        let z = phi([pose[0], pose[1], pose[2], zeta]);
        (0..4)
            .map(|i| (z[i] - expected[i]).abs())
            .fold(0.0, f64::max)
    };
    let (start, mid) = (error(false), error(true));
    assert!(
        mid < start / 10.0,
        "start of tick {start:e}, mid-tick {mid:e}"
    );
}

fn plan(sample: u64, horizon: u32, status: PlanStatus) -> Plan {
    let mut p = Plan {
        sample,
        horizon,
        status: status as u32,
        ..Plan::default()
    };
    for i in 0..horizon as usize {
        p.v[i] = [i as f64, 0.0];
    }
    p
}

#[test]
fn covering_element_is_the_age_of_the_plan_within_its_horizon() {
    let p = plan(10, 8, PlanStatus::Solved);
    assert_eq!(
        covering_element(&p, 9),
        None,
        "a plan covers nothing before its sample"
    );
    assert_eq!(covering_element(&p, 10), Some(0));
    assert_eq!(covering_element(&p, 17), Some(7));
    assert_eq!(covering_element(&p, 18), None, "exhausted after N samples");
}

#[test]
fn a_late_plan_is_held_until_the_sample_it_arrived_in() {
    let mut dfl = Dfl::new(&paper_arrival());
    let mut inbox = PlanInbox::new(0.05);
    let mut p = plan(100, 8, PlanStatus::Solved);
    // Lockstep: a solve of 2.5 Ts arrives 3 whole samples late.
    p.solve_ns = 125_000_000;
    let lockstep = protocol::task::SimulatedTime::at(1000, 0.005);
    let arrival_ns = lockstep.arrival_after_ns(5.0, p.solve_ns, 0.05);
    assert_eq!(inbox.receive(&p, arrival_ns), 103);
    assert!(inbox.has_received(100));
    let est = Estimate::default();
    inbox.release(102, &mut dfl);
    assert_eq!(dfl.step(&est, 1020).mode(), Some(CommandMode::Brake));
    inbox.release(103, &mut dfl);
    let a = dfl.step(&est, 1030);
    assert_eq!(
        (a.mode(), a.v),
        (Some(CommandMode::Shifted), [3.0, 0.0]),
        "element 3 of plan 100"
    );
    // Real time: received 1.2 Ts after its sample started, usable at once (sample 101).
    let mut inbox = PlanInbox::new(0.05);
    assert_eq!(
        inbox.receive(&plan(100, 8, PlanStatus::Solved), 60_000_000),
        101
    );
}

#[test]
fn the_dfl_waits_for_every_plan_unless_it_joined_after_the_previous_one() {
    let mut inbox = PlanInbox::new(0.05);
    assert!(inbox.waits_for(0), "from the start, plan 0 is waited for");
    assert!(
        !inbox.waits_for(40),
        "joined at sample 40: plan 39 never came"
    );
    inbox.receive(&plan(40, 8, PlanStatus::Solved), 0);
    assert!(!inbox.waits_for(40), "plan 40 is here");
    assert!(inbox.waits_for(41));
}

#[test]
fn a_joining_dfl_adopts_the_zeta_the_plant_is_driven_with() {
    let mut dfl = Dfl::new(&Scenario::default());
    dfl.adopt_zeta(0.8);
    assert_eq!(dfl.zeta(), 0.8);
    dfl.adopt_zeta(f64::NAN);
    assert_eq!(dfl.zeta(), 0.8);
}

#[test]
fn a_plan_arriving_exactly_at_the_deadline_meets_it_and_one_later_misses() {
    let mut m = DeadlineMonitor::new(0.05);
    assert!(m.commanded(10, true, CommandMode::Nominal).is_none());
    m.on_plan(&plan(10, 8, PlanStatus::Solved), 50_000_000);
    let v = m.commanded(11, true, CommandMode::Shifted).unwrap();
    assert_eq!((v.sample, v.met, v.misses_total), (10, 1, 0));
    assert!(m.commanded(11, false, CommandMode::Nominal).is_none());
    m.on_plan(&plan(11, 8, PlanStatus::Solved), 50_000_001);
    let v = m.commanded(12, true, CommandMode::Nominal).unwrap();
    assert_eq!(
        (v.sample, v.met, v.misses_total, v.fallback),
        (11, 0, 1, CommandMode::Shifted as u32)
    );
}

#[test]
fn a_sample_whose_first_tick_had_no_command_is_judged_a_command_later() {
    // Caught in a real-time test: the DFL braked alone on the first tick of sample 10
    // (its estimate late), so sample 10, whose plan came 75 ms late, was never judged.
    let mut m = DeadlineMonitor::new(0.05);
    assert!(
        m.commanded(9, false, CommandMode::Nominal).is_none(),
        "not from mid-sample"
    );
    m.commanded(9, true, CommandMode::Nominal);
    m.on_plan(&plan(9, 8, PlanStatus::Solved), 1_000_000);
    m.on_plan(&plan(10, 8, PlanStatus::Solved), 75_000_000);
    let v = m.commanded(10, false, CommandMode::Shifted).unwrap();
    assert_eq!((v.sample, v.met), (9, 1));
    let v = m.commanded(11, true, CommandMode::Nominal).unwrap();
    assert_eq!(
        (v.sample, v.met, v.fallback, v.misses_total),
        (10, 0, CommandMode::Shifted as u32, 1)
    );
    // Samples 12 and 13 with no command at all (the DFL itself stalled): each judged, one
    // a command, as braked; 13's plan never came.
    m.on_plan(&plan(11, 8, PlanStatus::Solved), 1_000_000);
    m.on_plan(&plan(12, 8, PlanStatus::Solved), 1_000_000);
    let samples: Vec<(u64, u32, u32)> = (140..143)
        .filter_map(|tick| m.commanded(tick / 10, tick % 10 == 0, CommandMode::Nominal))
        .map(|v| (v.sample, v.met, v.fallback))
        .collect();
    let (nominal, brake) = (CommandMode::Nominal as u32, CommandMode::Brake as u32);
    assert_eq!(
        samples,
        vec![(11, 1, nominal), (12, 1, brake), (13, 0, brake)],
        "the backlog, oldest first"
    );
}

#[test]
fn a_missing_or_failed_plan_is_a_miss_with_its_status() {
    let mut m = DeadlineMonitor::new(0.05);
    m.commanded(0, true, CommandMode::Brake);
    let v = m.commanded(1, true, CommandMode::Brake).unwrap();
    assert_eq!((v.met, v.status), (0, PLAN_MISSING));
    m.on_plan(&plan(1, 8, PlanStatus::NumericalError), 1_000_000);
    let v = m.commanded(2, true, CommandMode::Brake).unwrap();
    assert_eq!(
        (v.met, v.status, v.misses_total),
        (0, PlanStatus::NumericalError as u32, 2)
    );
}

#[test]
fn a_plan_older_than_its_horizon_is_exhausted_and_the_dfl_brakes() {
    let mut dfl = Dfl::new(&paper_arrival());
    assert!(dfl.offer(&plan(10, 8, PlanStatus::Solved)));
    let est = Estimate::default();
    assert_eq!(
        dfl.step(&est, 170).mode(),
        Some(CommandMode::Shifted),
        "element 7 still covers sample 17"
    );
    assert_eq!(
        dfl.step(&est, 180).mode(),
        Some(CommandMode::Brake),
        "nothing covers sample 18"
    );
}

#[test]
fn older_or_failed_plans_never_replace_the_active_one() {
    let mut dfl = Dfl::new(&Scenario::default());
    assert!(dfl.offer(&plan(5, 8, PlanStatus::Solved)));
    assert!(!dfl.offer(&plan(4, 8, PlanStatus::Solved)));
    assert!(!dfl.offer(&plan(6, 8, PlanStatus::Infeasible)));
    let est = Estimate {
        state: [7.0, 7.0, 0.0, 0.0],
        ..Estimate::default()
    };
    let a = dfl.step(&est, 6 * 10);
    assert_eq!(a.mode(), Some(CommandMode::Shifted));
    assert_eq!((a.plan_sample, a.v), (5, [1.0, 0.0]));
}

/// The default scenario with the paper's arrival: a robot at rest at its goal (the
/// origin) flies its plans rather than being held there.
fn paper_arrival() -> Scenario {
    let mut s = Scenario::default();
    s.robot.final_approach = protocol::FinalApproach::Paper;
    s
}

/// A robot at the origin heading along x at 1 m/s, an obstacle whose edge is 1 m
/// ahead; the safety check on or off.
fn approaching(gatekeeper: bool) -> (Dfl, Estimate) {
    let mut s = Scenario {
        obstacles: vec![protocol::Obstacle::fixed(1.5, 0.0, 0.5)],
        ..Scenario::default()
    };
    s.robot.zeta0 = 1.0;
    s.dfl.gatekeeper = gatekeeper;
    let estimate = Estimate {
        state: [0.0, 0.0, 0.0, 1.0],
        ..Estimate::default()
    };
    (Dfl::new(&s), estimate)
}

/// Plan `sample` accelerating at `ax` along x for 8 samples (0.4 s).
fn along_x(sample: u64, ax: f64) -> Plan {
    let mut p = plan(sample, 8, PlanStatus::Solved);
    p.v = [[ax, 0.0]; protocol::MAX_HORIZON];
    p
}

#[test]
fn a_plan_into_an_obstacle_is_refused_and_the_committed_one_goes_on() {
    // Braking at 2 m/s^2 for 0.4 s, then the brake: 0.25 m. Speeding up at 2 m/s^2:
    // 0.56 m, then 0.54 m to stop, into the obstacle 1 m ahead.
    let (mut dfl, estimate) = approaching(true);
    assert!(dfl.offer(&along_x(0, -2.0)));
    let a = dfl.step(&estimate, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Nominal), Some(Intervention::None))
    );
    assert!(dfl.offer(&along_x(1, 2.0)));
    let a = dfl.step(&estimate, 10);
    assert_eq!(a.intervention(), Some(Intervention::PlanRefused));
    assert_eq!(
        (a.mode(), a.plan_sample, a.v),
        (Some(CommandMode::Shifted), 0, [-2.0, 0.0])
    );
    assert!(a.intervention_clearance_m < 0.0);
    assert_eq!((a.safety_interventions, dfl.interventions()), (1, 1));
}

#[test]
fn without_a_committed_plan_an_unsafe_one_leaves_the_robot_braking() {
    let (mut dfl, estimate) = approaching(true);
    dfl.offer(&along_x(0, 2.0));
    let a = dfl.step(&estimate, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Brake), Some(Intervention::PlanRefused))
    );
    assert_eq!(
        a.linearizing_input,
        [-3.0, 0.0],
        "the brake at its deceleration"
    );
}

#[test]
fn an_estimate_that_shows_the_committed_trajectory_unsafe_brings_the_brake_until_a_plan_passes() {
    let (mut dfl, estimate) = approaching(true);
    dfl.offer(&along_x(0, -2.0));
    dfl.step(&estimate, 0);
    // The estimate jumps 0.8 m ahead: the rest of the plan and the brake now run 1.04 m.
    let jumped = Estimate {
        state: [0.8, 0.0, 0.0, 1.0],
        ..Estimate::default()
    };
    let a = dfl.step(&jumped, 1);
    assert_eq!(
        (a.mode(), a.intervention()),
        (
            Some(CommandMode::SafetyBrake),
            Some(Intervention::CommittedUnsafe)
        )
    );
    assert_eq!(a.plan_sample, 0);
    let a = dfl.step(&jumped, 2);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::SafetyBrake), Some(Intervention::None))
    );
    // A plan that stops in time from there (in 1/6 m) is committed and flown.
    dfl.offer(&along_x(1, -3.0));
    let a = dfl.step(&jumped, 10);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Nominal), Some(Intervention::None))
    );
    assert_eq!(dfl.interventions(), 1);
}

#[test]
fn a_committed_plan_swerving_away_flies_on_when_braking_would_go_in_deeper() {
    // A small obstacle straight ahead: braking along the heading runs through it (5 cm
    // deep), the committed plan's swerve clips it by 1.6 cm.
    let mut s = Scenario {
        obstacles: vec![protocol::Obstacle::fixed(0.15, 0.0, 0.05)],
        ..Scenario::default()
    };
    s.robot.zeta0 = 1.0;
    let mut dfl = Dfl::new(&s);
    let mut swerve = plan(0, 8, PlanStatus::Solved);
    swerve.v = [[0.0, 3.0]; protocol::MAX_HORIZON];
    dfl.offer(&swerve);
    let far = Estimate {
        state: [-5.0, 0.0, 0.0, 1.0],
        ..Estimate::default()
    };
    assert_eq!(dfl.step(&far, 0).intervention(), Some(Intervention::None));
    let close = Estimate {
        state: [0.0, 0.0, 0.0, 1.0],
        ..Estimate::default()
    };
    let a = dfl.step(&close, 1);
    assert_eq!(
        (a.mode(), a.intervention()),
        (
            Some(CommandMode::Nominal),
            Some(Intervention::MovingContact)
        ),
        "every choice touches while moving: the one that keeps the most clearance, said so"
    );
    assert!((-0.02..-0.01).contains(&a.intervention_clearance_m));
    // Flown on, reported once.
    let a = dfl.step(&close, 2);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Nominal), Some(Intervention::None))
    );
    assert_eq!(dfl.interventions(), 1);
}

#[test]
fn an_older_plan_never_replaces_a_newer_one_given_up() {
    let (mut dfl, estimate) = approaching(true);
    dfl.offer(&along_x(5, -2.0));
    dfl.step(&estimate, 50);
    let jumped = Estimate {
        state: [0.8, 0.0, 0.0, 1.0],
        ..Estimate::default()
    };
    assert_eq!(dfl.step(&jumped, 51).mode(), Some(CommandMode::SafetyBrake));
    assert!(!dfl.offer(&along_x(4, -3.0)), "plan 4 is older than plan 5");
}

#[test]
fn without_the_safety_check_the_unsafe_plan_is_flown() {
    let (mut dfl, estimate) = approaching(false);
    dfl.offer(&along_x(0, 2.0));
    let a = dfl.step(&estimate, 0);
    assert_eq!(
        (a.mode(), a.v, a.intervention()),
        (
            Some(CommandMode::Nominal),
            [2.0, 0.0],
            Some(Intervention::None)
        )
    );
}

#[test]
fn without_a_covering_plan_the_dfl_brakes_zeta_to_zero_without_steering() {
    let mut s = Scenario::default();
    s.robot.zeta0 = 1.0;
    let mut dfl = Dfl::new(&s);
    let est = Estimate {
        state: [7.0, 7.0, 0.0, 1.0],
        ..Estimate::default()
    };
    let mut last = dfl.zeta();
    // The speed falls at the braking deceleration, to exactly zero.
    let per_tick = s.brake_decel() * s.timing.dt_s();
    for tick in 0..200 {
        let a = dfl.step(&est, tick);
        assert_eq!(a.mode(), Some(CommandMode::Brake));
        assert_eq!(a.u2, 0.0);
        let expected = (last - per_tick).max(0.0);
        assert!(
            (a.zeta - expected).abs() < 1e-9,
            "tick {tick}: zeta {} not {expected}",
            a.zeta
        );
        last = a.zeta;
    }
    assert_eq!(dfl.zeta(), 0.0);
}

#[test]
fn where_the_wheels_saturate_zeta_is_held_at_the_speed_they_realize() {
    // Wheels of 10 rad/s and radius 0.1 m: 1 m/s at most. Braking at 3 m/s^2 from
    // zeta0 = 2 m/s (a value the wheels never realize): zeta is held at the 1 m/s they do
    // and falls from there, not from 2.
    let s = Scenario::default()
        .with_overrides(&[
            "plant.max_wheel_speed_rad_s=10".into(),
            "robot.zeta0=2".into(),
        ])
        .unwrap();
    let mut dfl = Dfl::new(&s);
    let first = dfl.brake(0);
    assert!((first.zeta - 1.0).abs() < 1e-12, "{}", first.zeta);
    let second = dfl.brake(1);
    assert!((second.zeta - (1.0 - 3.0 * s.timing.dt_s())).abs() < 1e-12);
    // Without a wheel limit zeta integrates the input as before.
    let mut free = Dfl::new(
        &Scenario::default()
            .with_overrides(&["robot.zeta0=2".into()])
            .unwrap(),
    );
    assert!((free.brake(0).zeta - (2.0 - 3.0 * s.timing.dt_s())).abs() < 1e-12);
}

/// A scenario whose only obstacle, a person (0.3 m), starts at `(x, 0)` and walks along x
/// at 1 m/s.
fn walking_at_the_origin(x: f64) -> Scenario {
    Scenario {
        obstacles: vec![protocol::Obstacle {
            velocity: [1.0, 0.0],
            ..protocol::Obstacle::fixed(x, 0.0, 0.3)
        }],
        ..Scenario::default()
    }
}

#[test]
fn a_robot_at_rest_flees_no_farther_than_it_can_stop_before_the_person_catches_it() {
    // At rest at the origin, a person 0.2 m away coming at the robot at 1 m/s: staying
    // (the brake) is run into at once, at rest; the whole plan sideways is caught while
    // the robot still speeds away, but the plan cut short comes to rest first, a little
    // out of the way.
    let mut s = walking_at_the_origin(-0.5);
    s.robot.zeta0 = 0.0;
    // At its goal: a robot that settles there is not held where it would be run into.
    for arrival in [
        protocol::FinalApproach::Paper,
        protocol::FinalApproach::Settle,
    ] {
        s.robot.final_approach = arrival;
        flees_no_farther_than_it_can_stop(&s);
    }
}

fn flees_no_farther_than_it_can_stop(s: &Scenario) {
    let person = one_track(0.0, [-0.5, 0.0], [1.0, 0.0]);
    let mut dfl = Dfl::new(s);
    dfl.set_tracks(&person);
    let at_rest = Estimate::default();
    let mut towards = plan(0, 20, PlanStatus::Solved);
    towards.v = [[-3.0, 0.0]; protocol::MAX_HORIZON];
    dfl.offer(&towards);
    let a = dfl.step(&at_rest, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Brake), Some(Intervention::PlanRefused)),
        "into the person, whole or cut short, is worse than staying"
    );
    let mut sideways = plan(1, 20, PlanStatus::Solved);
    sideways.v = [[0.0, 3.0]; protocol::MAX_HORIZON];
    let mut gatekeeper = Gatekeeper::new(s);
    gatekeeper.set_tracks(&person);
    let now = Moment {
        sample: 1,
        into_sample_s: 0.0,
    };
    let staying = gatekeeper.brake_verdict([0.0; 4], now, 0.0);
    let whole = gatekeeper.verdict(&sideways, now, [0.0; 4], 0.0);
    assert!(staying.rests_before_contact() && whole.moving.is_some());
    dfl.offer(&sideways);
    let a = dfl.step(&at_rest, 10);
    assert_eq!(
        (a.mode(), a.intervention(), a.plan_sample),
        (
            Some(CommandMode::ZetaGuard),
            Some(Intervention::LeastUnsafe),
            1
        ),
        "out of the way, cut short to come to rest before the person comes"
    );
    let deepest = staying.deepest().unwrap();
    assert!((deepest..0.0).contains(&a.intervention_clearance_m));
    assert_eq!(dfl.interventions(), 2);
}

#[test]
fn a_plan_out_of_the_way_that_stops_before_the_person_comes_is_taken_over_staying() {
    // At rest at the origin, a person 0.7 m away coming at the robot at 1 m/s. Out of
    // its way sideways, 12 cm, and at rest after 0.4 s: the person's disc reaches the
    // robot later (from 0.72 s), but at rest and less deeply than staying where it is.
    let mut s = walking_at_the_origin(-1.0);
    // Checked for 1 s ahead (N Ts), on the way to a goal farther on.
    s.mpc.horizon = 20;
    s.robot.goal.position = [0.0, 3.0];
    let mut dfl = Dfl::new(&s);
    dfl.set_tracks(&one_track(0.0, [-1.0, 0.0], [1.0, 0.0]));
    let mut out_and_stop = plan(0, 20, PlanStatus::Solved);
    out_and_stop.v = [[0.0; 2]; protocol::MAX_HORIZON];
    for i in 0..8 {
        out_and_stop.v[i] = [0.0, if i < 4 { 3.0 } else { -3.0 }];
    }
    dfl.offer(&out_and_stop);
    let a = dfl.step(&Estimate::default(), 0);
    assert_eq!(
        (a.mode(), a.intervention(), a.plan_sample),
        (
            Some(CommandMode::ZetaGuard),
            Some(Intervention::LeastUnsafe),
            0
        ),
        "out of the way (turning towards it first), though the grown disc reaches it at rest"
    );
    assert!(a.intervention_clearance_m < 0.0);
}

/// A refused and a committed plan of 8 elements, whole.
const REFUSED: Candidate = Candidate::Refused { stages: 8 };
const COMMITTED: Candidate = Candidate::Committed { stages: 8 };

fn verdict(moving: Option<f64>, resting: Option<f64>) -> Verdict {
    Verdict { moving, resting }
}

#[test]
fn a_trajectory_that_enters_no_disc_is_taken_before_any_that_touches() {
    let clear = verdict(None, None);
    for touching in [verdict(Some(-0.01), None), verdict(None, Some(-1e-6))] {
        for order in [
            [(Candidate::Brake, touching), (REFUSED, clear)],
            [(REFUSED, clear), (Candidate::Brake, touching)],
        ] {
            assert_eq!(least_unsafe(&order), Some((REFUSED, clear)));
        }
    }
    assert_eq!(least_unsafe(&[]), None);
}

#[test]
fn one_at_rest_at_its_first_contact_is_taken_before_one_that_touches_less_while_moving() {
    let caught_at_rest = verdict(None, Some(-0.3));
    let grazed_moving = verdict(Some(-1e-4), None);
    // Touched at rest less deeply than it also touches while moving: still moving.
    let both = verdict(Some(-0.2), Some(-0.01));
    for moving in [grazed_moving, both] {
        for order in [
            [(COMMITTED, moving), (Candidate::Brake, caught_at_rest)],
            [(Candidate::Brake, caught_at_rest), (COMMITTED, moving)],
        ] {
            assert_eq!(
                least_unsafe(&order),
                Some((Candidate::Brake, caught_at_rest))
            );
        }
    }
}

#[test]
fn among_the_same_kind_the_most_clearance_is_taken_and_a_tie_goes_to_the_first() {
    let at_rest = |c| verdict(None, Some(c));
    let moving = |c| verdict(Some(c), None);
    for kind in [at_rest, moving] {
        let candidates = [
            (Candidate::Brake, kind(-0.2)),
            (COMMITTED, kind(-0.05)),
            (REFUSED, kind(-0.1)),
        ];
        assert_eq!(least_unsafe(&candidates), Some((COMMITTED, kind(-0.05))));
        let tied = [(Candidate::Brake, kind(-0.1)), (REFUSED, kind(-0.1))];
        assert_eq!(least_unsafe(&tied), Some((Candidate::Brake, kind(-0.1))));
    }
    // The deepest of either kind is a trajectory's clearance.
    let both = verdict(Some(-0.01), Some(-0.4));
    assert_eq!(
        least_unsafe(&[(Candidate::Brake, both), (REFUSED, moving(-0.2))]),
        Some((REFUSED, moving(-0.2)))
    );
}

#[test]
fn in_fuzz_world_74_the_robot_does_not_flee_where_the_person_would_catch_it_moving() {
    // World 74 of `scmpc fuzz --seed 5` at 9.172 s (tick 1190): the robot nearly at rest
    // beside an obstacle at rest on its east; a person (0.306 m) walking at 1.36 m/s
    // coming at it from the west. The DFL flew the plan of that sample (its first input
    // held here: north along the obstacle at 1.16 m/s^2), which the person's grown disc
    // catches while the robot still moves; before this rule it was taken for keeping the
    // most clearance, and the robot was touched reversing at 0.24 m/s 0.46 s later.
    let mut s = Scenario {
        obstacles: vec![
            protocol::Obstacle::fixed(6.662134021181566, 1.4671399473179507, 0.5992135890788054),
            protocol::Obstacle {
                velocity: [1.284221898656126, -0.45052663235948387],
                ..protocol::Obstacle::fixed(
                    -6.602581622798066,
                    5.4369553007038665,
                    0.3062412917203312,
                )
            },
        ],
        ..Scenario::default()
    };
    s.timing.ts_s = 0.07707550684315743;
    s.mpc.horizon = 14;
    s.mpc.v_max = 1.560182149099031;
    s.robot.radius_m = 0.018349166328605258;
    let mut gatekeeper = Gatekeeper::new(&s);
    let mut tracks = one_track(
        9.172,
        [5.176282772024276, 1.3047316449855453],
        [1.2842229003741272, -0.4505269837791169],
    );
    tracks.tracks[0].obstacle = 1;
    tracks.tracks[0].radius_m = 0.3062412917203312;
    gatekeeper.set_tracks(&tracks);
    let now = Moment {
        sample: 119,
        into_sample_s: 0.0,
    };
    let z = phi([
        6.015764344416543,
        1.2564255960698423,
        -1.3228472281542505,
        -0.0065,
    ]);
    let grow = gatekeeper.keep_growth(0.01);
    let mut north = plan(119, 14, PlanStatus::Solved);
    north.v = [[0.055188714534768084, 1.1585442250391778]; protocol::MAX_HORIZON];
    let flight = gatekeeper.verdict(&north, now, z, grow);
    let staying = gatekeeper.brake_verdict(z, now, grow);
    assert!(flight.moving.is_some(), "{flight:?}");
    assert!(
        staying.rests_before_contact() && !staying.clear(),
        "{staying:?}"
    );
    assert!(
        flight.deepest() > staying.deepest(),
        "by clearance alone the flight: {flight:?} against {staying:?}"
    );
    let whole = Candidate::Refused { stages: 14 };
    assert_eq!(
        least_unsafe(&[(Candidate::Brake, staying), (whole, flight)]),
        Some((Candidate::Brake, staying))
    );
    // With the flight cut short after each element too, what the DFL flies comes to rest
    // before the person's disc reaches it.
    let chosen = match choose(&gatekeeper, (now, z, grow), None, Some(&north)) {
        Choice::Brake(None, verdict, _) => verdict,
        Choice::Refused(verdict, stages) if stages < 14 => verdict,
        other => panic!("{other:?}"),
    };
    assert!(chosen.rests_before_contact(), "{chosen:?}");
}

/// The tracks at `time_s` of one obstacle (0.3 m) at `center` moving at `velocity`, with
/// 1 cm of position sigma.
pub(crate) fn one_track(time_s: f64, center: [f64; 2], velocity: [f64; 2]) -> protocol::Tracks {
    let mut tracks = [protocol::Track::default(); protocol::MAX_TRACKS];
    tracks[0] = protocol::Track {
        radius_m: 0.3,
        center,
        velocity,
        covariance: [1e-4, 0.0, 1e-4, 1e-4, 0.0, 1e-4],
        ..protocol::Track::default()
    };
    protocol::Tracks {
        header: protocol::Header {
            time_s,
            ..protocol::Header::default()
        },
        count: 1,
        tracks,
        ..protocol::Tracks::default()
    }
}

#[test]
fn a_slow_robot_within_the_goal_tolerance_is_braked_to_rest_and_held_until_pushed_away() {
    // The default scenario settles at its goal, the origin, within 0.1 m.
    let mut dfl = Dfl::new(&Scenario::default());
    dfl.adopt_zeta(0.05);
    let at = |x: f64| Estimate {
        state: [x, 0.0, 0.0, 0.0],
        ..Estimate::default()
    };
    let flown = |a: Actuation| a.mode() != Some(CommandMode::Hold);
    dfl.offer(&along_x(0, 1.0));
    assert!(flown(dfl.step(&at(0.05), 0)), "0.05 m/s: too fast to hold");
    dfl.adopt_zeta(0.01);
    assert!(flown(dfl.step(&at(0.15), 1)), "slow, 0.15 m out");
    let held = dfl.step(&at(0.05), 2);
    assert_eq!(held.mode(), Some(CommandMode::Hold));
    assert_eq!(
        (held.linearizing_input[1], held.zeta),
        (0.0, 0.0),
        "braked to rest"
    );
    // A plan goes on being offered; the robot stays held within twice the tolerance.
    dfl.offer(&along_x(1, 1.0));
    let held = dfl.step(&at(0.19), 10);
    assert_eq!(
        (held.mode(), held.u1, held.u2),
        (Some(CommandMode::Hold), 0.0, 0.0)
    );
    assert!(flown(dfl.step(&at(0.21), 11)), "let go");
    // A plan that takes the robot out of the tolerance (out of a person's way) is flown.
    let mut away = along_x(2, 1.0);
    away.z[3] = [0.5, 0.0, 0.0, 0.0];
    dfl.offer(&away);
    assert!(
        flown(dfl.step(&at(0.05), 20)),
        "the plan leaves the tolerance"
    );
    // With a goal heading the held robot turns in place to it, then stops turning.
    let mut facing = Scenario::default();
    facing.robot.goal.yaw_rad = Some(1.0);
    let mut dfl = Dfl::new(&facing);
    let turning = |dfl: &mut Dfl, theta: f64, tick| {
        let estimate = Estimate {
            state: [0.0, 0.0, theta, 0.0],
            ..Estimate::default()
        };
        let a = dfl.step(&estimate, tick);
        assert_eq!((a.mode(), a.zeta), (Some(CommandMode::Hold), 0.0));
        a.u2
    };
    assert_eq!(
        turning(&mut dfl, 0.0, 0),
        TURN_RATE_RAD_S,
        "1 rad off: at the fastest"
    );
    assert!(
        (turning(&mut dfl, 0.8, 1) - 0.4).abs() < 1e-12,
        "0.2 rad off"
    );
    assert!(
        (turning(&mut dfl, 1.3, 2) + 0.6).abs() < 1e-12,
        "past it: back"
    );
    assert_eq!(turning(&mut dfl, 1.04, 3), 0.0, "within half the tolerance");
    // The paper's arrival holds nothing.
    let mut paper = Scenario::default();
    paper.robot.final_approach = protocol::FinalApproach::Paper;
    let mut dfl = Dfl::new(&paper);
    dfl.offer(&along_x(0, 1.0));
    assert!(flown(dfl.step(&at(0.0), 0)));
}

#[test]
fn a_plan_cut_short_is_flown_to_its_cut_and_then_the_robot_brakes() {
    let mut dfl = Dfl::new(&Scenario::default());
    let plan = along_x(1, 1.0);
    let cut = Verdict {
        moving: None,
        resting: Some(-0.1),
    };
    // Elements 0, 1 and 2 of plan 1, then the brake.
    let outcome = dfl.take(Choice::Refused(cut, 3), Some((plan, -0.2)));
    assert_eq!(
        (outcome.intervention, outcome.count),
        (Intervention::LeastUnsafe, 1)
    );
    let estimate = Estimate {
        state: [-5.0, 0.0, 0.0, 0.5],
        ..Estimate::default()
    };
    let ticks = Scenario::default().timing.inner_steps as u64;
    let flown = dfl.step(&estimate, 3 * ticks);
    assert_ne!(flown.mode(), Some(CommandMode::Brake));
    assert_eq!(flown.plan_sample, 1);
    let braked = dfl.step(&estimate, 4 * ticks);
    assert_eq!(
        (braked.mode(), braked.plan_sample),
        (Some(CommandMode::Brake), 0)
    );
}

/// A robot at rest at the origin, heading along x on its way to a goal 5 m ahead, and a
/// person (0.3 m) at `(x, -1)` walking along y at 1 m/s: across its way, at it when `x`
/// is 0.
fn crossing_at(x: f64, evasion: bool) -> Dfl {
    let mut s = Scenario {
        obstacles: vec![protocol::Obstacle {
            velocity: [0.0, 1.0],
            ..protocol::Obstacle::fixed(x, -1.0, 0.3)
        }],
        ..Scenario::default()
    };
    s.robot.goal.position = [5.0, 0.0];
    s.dfl.evasion = evasion;
    let mut dfl = Dfl::new(&s);
    dfl.set_tracks(&one_track(0.0, [x, -1.0], [0.0, 1.0]));
    dfl
}

#[test]
fn a_robot_at_rest_that_a_person_would_walk_into_steps_out_of_the_way_along_its_heading() {
    let at_rest = Estimate::default();
    let mut dfl = crossing_at(0.0, true);
    let a = dfl.step(&at_rest, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Evasion), Some(Intervention::Evasion))
    );
    assert!(
        a.v[0] > 0.0 && a.v[1] == 0.0,
        "not forwards along the heading: {:?}",
        a.v
    );
    assert!(
        a.intervention_clearance_m < 0.0,
        "staying would not be run into"
    );
    // What is flown passes the commit check, as an MPC plan must.
    let (gatekeeper, flown) = (dfl.gatekeeper.as_ref().unwrap(), dfl.active.unwrap());
    let now = Moment {
        sample: 0,
        into_sample_s: 0.0,
    };
    let grow = gatekeeper.commit_growth(at_rest.position_sigma());
    assert_eq!(gatekeeper.check(&flown, now, [0.0; 4], grow), None);
    // The evasion is flown on, checked as a committed trajectory, without a new one.
    let b = dfl.step(&at_rest, 1);
    assert_eq!(
        (b.mode(), b.intervention(), b.v),
        (Some(CommandMode::Evasion), Some(Intervention::None), a.v)
    );
    assert_eq!(dfl.interventions(), 1);

    let mut staying = crossing_at(0.0, false);
    let a = staying.step(&at_rest, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Brake), Some(Intervention::None)),
        "dfl.evasion = false"
    );
    let mut passing = crossing_at(2.0, true);
    let a = passing.step(&at_rest, 0);
    assert_eq!(
        (a.mode(), a.intervention()),
        (Some(CommandMode::Brake), Some(Intervention::None)),
        "a person who passes 2 m ahead"
    );
}

#[test]
fn an_evasion_drives_straight_along_the_heading_and_its_states_follow_its_inputs() {
    let start = evasion::Start {
        now: Moment {
            sample: 7,
            into_sample_s: 0.02,
        },
        z: protocol::phi([1.0, 2.0, 0.5, 0.4]),
        heading_rad: 0.5,
        zeta_m_s: 0.4,
    };
    let limits = evasion::Limits {
        accel_m_s2: 2.0,
        most_speed_m_s: f64::INFINITY,
        ts_s: 0.05,
    };
    let plan = evasion::evasion_plan(start, -1.0, 6, limits);
    assert_eq!((plan.sample, plan.horizon), (7, 6));
    let backwards = [-2.0 * 0.5f64.cos(), -2.0 * 0.5f64.sin()];
    assert!(plan.v[..6].iter().all(|&v| v == backwards), "{:?}", plan.v);
    // Braking from 0.4 m/s, then reversing: for 0.03 s (the rest of sample 7), then a
    // sample of 0.05 s each; the state at each sample's start, the first one now.
    for i in 0..=6 {
        let t = if i == 0 {
            0.0
        } else {
            0.03 + (i - 1) as f64 * 0.05
        };
        let speed = 0.4 - 2.0 * t;
        let along = 0.4 * t - 0.5 * 2.0 * t * t;
        let x_bar = [
            1.0 + along * 0.5f64.cos(),
            2.0 + along * 0.5f64.sin(),
            0.5,
            speed,
        ];
        let wanted = protocol::phi(x_bar);
        for (got, wanted) in plan.z[i].iter().zip(wanted) {
            assert!((got - wanted).abs() < 1e-12, "z_{i} {:?}", plan.z[i]);
        }
    }
    let end = evasion::end_speed_m_s(start, -1.0, 6, limits);
    assert!((end - (0.4 - 2.0 * 0.28)).abs() < 1e-12);
}
