//! The MPC against an obstacle that moves: each stage's CBF on the disc its track
//! predicts for that stage's time.

use super::*;

/// The crossing world: the robot from (-4, 0) to (4, 0), a person of radius 0.3 m
/// crossing its way at x = 0.5 upwards at 1 m/s, level with it at t = 5 s.
fn crossing() -> Scenario {
    let mut s = Scenario::default();
    s.robot.start = [-4.0, 0.0, 0.0];
    s.robot.goal.position = [4.0, 0.0];
    s.obstacles = vec![Obstacle {
        velocity: [0.0, 1.0],
        ..Obstacle::fixed(0.5, -5.0, 0.3)
    }];
    s
}

/// The tracks of a perfect tracker at `t_s`: the true centre and velocity, no doubt.
fn exact_tracks(s: &Scenario, t_s: f64) -> Tracks {
    let mut tracks = Tracks::default();
    for (i, o) in s.obstacles.iter().enumerate() {
        tracks.tracks[i] = protocol::Track {
            obstacle: i as u32,
            radius_m: o.radius,
            center: o.center_at(t_s),
            velocity: o.velocity_at(t_s),
            ..protocol::Track::default()
        };
    }
    tracks.count = s.obstacles.len() as u32;
    tracks.header.time_s = t_s;
    tracks
}

/// 300 samples of the crossing in closed loop on the MPC's own model, the tracks of a
/// perfect tracker given to the MPC when `tracked`; calls `each` with every sample's time,
/// its plan and the state after it.
fn crossing_loop(tracked: bool, mut each: impl FnMut(f64, &Plan, Vector4<f64>)) {
    let s = crossing();
    let ts = s.timing.ts_s;
    let mut mpc = LinearMpc::new(&s).unwrap();
    let (a, b) = model::discretize(ts);
    let [x, y, theta] = s.robot.start;
    let mut z = Vector4::from(protocol::phi([x, y, theta, 0.0]));
    for k in 0..300 {
        let t = k as f64 * ts;
        if tracked {
            mpc.set_tracks(&exact_tracks(&s, t));
        }
        let plan = mpc.step(k, protocol::phi_inverse(z.into(), theta), 0.0);
        z = a * z + b * nalgebra::Vector2::from(plan.v[0]);
        each(t, &plan, z);
    }
}

#[test]
fn every_stage_of_every_plan_keeps_clear_of_where_the_obstacle_will_be() {
    let s = crossing();
    let (person, ts) = (&s.obstacles[0], s.timing.ts_s);
    let mut least = f64::INFINITY;
    let mut last = Vector4::zeros();
    crossing_loop(true, |t, plan, z| {
        assert!(plan.is_solved(), "t = {t}: {:?}", plan.status());
        for i in 0..=plan.horizon as usize {
            let p = [plan.z[i][0], plan.z[i][2]];
            let center = person.center_at(t + i as f64 * ts);
            let clearance = protocol::distance(p, center) - 0.3;
            assert!(clearance > 0.0, "t = {t}, stage {i}: {clearance} m");
            least = least.min(clearance);
        }
        last = z;
    });
    // It met the person on its way (5 m off at the start: the test is not vacuous) and
    // went on past the way the person crossed.
    assert!(least < 1.0, "least clearance {least} m");
    assert!(last[0] > 1.0, "{last:?}");
}

#[test]
fn the_same_crossing_without_tracks_runs_through_the_person() {
    // No tracks heard: the MPC knows no obstacle, and the straight way meets the person.
    let s = crossing();
    let (person, ts) = (&s.obstacles[0], s.timing.ts_s);
    let mut least = f64::INFINITY;
    crossing_loop(false, |t, _, z| {
        let center = person.center_at(t + ts);
        least = least.min(protocol::distance([z[0], z[2]], center) - 0.3);
    });
    assert!(least < 0.0, "least clearance {least} m");
}

#[test]
fn a_disc_at_rest_is_itself_at_every_stage_and_a_moving_one_moves_and_grows() {
    let still = Disc::still([1.0, 2.0], 0.5);
    assert_eq!(still.at(0.4), still);
    assert_eq!(still.swept(2.0), still);
    let moving = Disc {
        motion: protocol::DiscMotion {
            velocity: [1.0, 0.0],
            radius_rate: 0.1,
            radius_accel: 0.25,
            hidden: false,
            standing: false,
            held: false,
        },
        ..still
    };
    let later = moving.at(2.0);
    assert_eq!(later.center, [3.0, 2.0]);
    assert!((later.radius - (0.5 + 0.2 + 1.0)).abs() < 1e-12);
    // Stepping twice is stepping once.
    let twice = moving.at(1.0).at(1.0);
    assert!((twice.radius - later.radius).abs() < 1e-12 && twice.center == later.center);
    // The swept disc holds the moving one over the whole time.
    let swept = moving.swept(2.0);
    for k in 0..=20 {
        let d = moving.at(k as f64 * 0.1);
        assert!(protocol::distance(d.center, swept.center) + d.radius <= swept.radius + 1e-12);
    }
    // Carried on at its velocity (the terminal rows' rest lookahead), the swept disc is
    // held all along that way, no larger than it; a disc at rest carried at none is itself.
    let velocity = moving.motion.velocity;
    let carried = swept.carried_on(velocity, 0.5);
    for k in 0..=10 {
        let t = k as f64 * 0.05;
        let on = [
            swept.center[0] + velocity[0] * t,
            swept.center[1] + velocity[1] * t,
        ];
        assert!(protocol::distance(on, carried.center) + swept.radius <= carried.radius + 1e-12);
    }
    assert!((carried.radius - (swept.radius + 0.25)).abs() < 1e-12);
    assert_eq!(still.carried_on([0.0; 2], 0.5), still);
}

/// The robot at rest at the origin (its goal 3 m north), a person of radius 0.3 m at
/// `(center_x, 0)` walking east at it at 1 m/s.
fn walked_at(center_x: f64) -> Scenario {
    let mut s = Scenario::default();
    s.robot.start = [0.0, 0.0, 0.0];
    s.robot.goal.position = [0.0, 3.0];
    s.obstacles = vec![Obstacle {
        velocity: [1.0, 0.0],
        ..Obstacle::fixed(center_x, 0.0, 0.3)
    }];
    s
}

/// The world of the escape plan below: the walker 1.1 m off, bounded at 3 m/s^2, and
/// passive safety alone (`mpc.rest_lookahead_s = 0`).
fn cornered() -> Scenario {
    let mut s = walked_at(-1.1);
    s.mpc.rest_lookahead_s = 0.0;
    s.perception.accel_max = 3.0;
    s
}

/// The robot at rest at its start, `[x, y, theta, zeta]`.
fn at_rest(s: &Scenario) -> [f64; 4] {
    let [x, y, theta] = s.robot.start;
    [x, y, theta, 0.0]
}

/// The plan of sample 0 from the robot's start at rest, with a perfect tracker's tracks,
/// the first numbered `obstacle` (0, or another robot's from [`protocol::FIRST_PEER`]).
fn first_plan(s: &Scenario, obstacle: u32) -> Plan {
    let mut mpc = LinearMpc::new(s).unwrap();
    let mut tracks = exact_tracks(s, 0.0);
    tracks.tracks[0].obstacle = obstacle;
    mpc.set_tracks(&tracks);
    mpc.step(0, at_rest(s), 0.0)
}

#[test]
fn a_robot_at_rest_that_no_plan_keeps_clear_of_the_bounded_discs_is_offered_an_escape() {
    // At rest at the origin, a person (0.3 m) 0.8 m away walking at it at 1 m/s: the
    // disc grown by accel_max t^2 / 2 soon covers everywhere the robot can reach. Passive
    // safety alone (`mpc.rest_lookahead_s = 0`), so that the stop below is the one to check
    // (with the lookahead, the next test).
    let s = cornered();
    let plan_with = |accel_max: f64| {
        let mut s = s.clone();
        s.perception.accel_max = accel_max;
        first_plan(&s, 0)
    };
    // With no acceleration bound the bounded program has a plan at once.
    let at_constant_velocity = plan_with(0.0);
    assert!(at_constant_velocity.is_solved());
    // With 3 m/s^2 the bounded program has none: after it failed, the step offers the
    // plan of the constant-velocity prediction.
    let escape = plan_with(3.0);
    assert!(escape.is_solved(), "{:?}", escape.status());
    assert!(
        escape.solves > at_constant_velocity.solves,
        "the bounded program first"
    );
    // Its stop from its last state, braking along its velocity, stays clear of the
    // person walking on over that stop (its terminal rows sweep the disc over the plan's
    // own stop, not the longest one).
    let n = escape.horizon as usize;
    let [x, xdot, y, ydot] = escape.z[n];
    let speed = xdot.hypot(ydot);
    let (decel, ts) = (s.brake_decel(), s.timing.ts_s);
    let stop_s = speed / decel + ts;
    for k in 0..=100 {
        let t = stop_s * f64::from(k) / 100.0;
        let travelled = if speed > 0.0 {
            (speed * t - 0.5 * decel * t * t).clamp(0.0, speed * speed / (2.0 * decel))
        } else {
            0.0
        };
        let at = [
            x + xdot / speed.max(1e-12) * travelled,
            y + ydot / speed.max(1e-12) * travelled,
        ];
        let center = s.obstacles[0].center_at(n as f64 * ts + t);
        assert!(protocol::distance(at, center) > 0.3, "{t} s into the stop");
    }
    let person = &s.obstacles[0];
    for i in 0..=escape.horizon as usize {
        let p = [escape.z[i][0], escape.z[i][2]];
        let center = person.center_at(i as f64 * s.timing.ts_s);
        assert!(protocol::distance(p, center) > 0.3, "stage {i}");
    }
}

#[test]
fn the_last_resort_escapes_another_robot_for_passive_safety_alone_not_a_person() {
    // The world of the escape above with the walker 0.1 m nearer, at the default lookahead:
    // keeping the stop out of its way half a second more leaves the bounded program and
    // the escape program no solution this close. The step's last resort, another robot's
    // only, is the escape program of passive safety alone.
    let mut s = walked_at(-1.0);
    s.perception.accel_max = 3.0;
    let plan_with = |rest_lookahead_s: f64, obstacle: u32| {
        let mut s = s.clone();
        s.mpc.rest_lookahead_s = rest_lookahead_s;
        first_plan(&s, obstacle)
    };
    let lookahead_s = s.mpc.rest_lookahead_s;
    assert!(lookahead_s > 0.0);
    let person = plan_with(lookahead_s, 0);
    assert!(!person.is_solved(), "a person: no last resort");
    let robot = protocol::FIRST_PEER + 1;
    let passive = plan_with(0.0, robot);
    assert!(passive.is_solved(), "{:?}", passive.status());
    let last_resort = plan_with(lookahead_s, robot);
    assert!(last_resort.is_solved(), "{:?}", last_resort.status());
    // Then the escape program of passive safety alone, solved from another start.
    assert_is_the_last_resort(&last_resort, &passive);
}

/// `last_resort` tried the programs with the rest lookahead first (more solves than
/// `passive`), then flew `passive`'s plan, the escape of passive safety alone.
fn assert_is_the_last_resort(last_resort: &Plan, passive: &Plan) {
    assert!(
        last_resort.solves > passive.solves,
        "the programs with the lookahead first ({} solves, {} without)",
        last_resort.solves,
        passive.solves
    );
    for (with, without) in last_resort.z.iter().zip(&passive.z) {
        for (a, b) in with.iter().zip(without) {
            assert!((a - b).abs() < 1e-6, "{with:?} against {without:?}");
        }
    }
}

#[test]
fn among_other_robots_a_person_walking_at_the_robot_no_longer_keeps_it_from_the_last_resort() {
    // The person of the test above, and another robot 10 m away: the last resort is taken
    // whenever another robot moves, however far (since ee09c77), and not for one at rest.
    let mut s = walked_at(-1.0);
    s.perception.accel_max = 3.0;
    let with_robot = |velocity: [f64; 2]| {
        let mut s = s.clone();
        s.obstacles.push(Obstacle {
            velocity,
            ..Obstacle::fixed(10.0, 10.0, 0.3)
        });
        let mut mpc = LinearMpc::new(&s).unwrap();
        let mut tracks = exact_tracks(&s, 0.0);
        tracks.tracks[1].obstacle = protocol::FIRST_PEER + 1;
        mpc.set_tracks(&tracks);
        mpc.step(0, at_rest(&s), 0.0)
    };
    let moving = with_robot([0.0, 1.0]);
    assert!(moving.is_solved(), "{:?}", moving.status());
    let standing = with_robot([0.0, 0.0]);
    assert!(!standing.is_solved(), "a robot at rest: no last resort");
    // The plan of the last resort, after the programs with the lookahead, is the
    // person's escape of passive safety alone.
    s.mpc.rest_lookahead_s = 0.0;
    let passive = first_plan(&s, 0);
    assert_is_the_last_resort(&moving, &passive);
}

#[test]
fn a_step_after_an_escape_plan_tries_the_bounded_program_once_unrelaxed_at_the_shifted_plan() {
    // The world of the escape above: no bounded plan at sample 0, nor at sample 1 with the
    // walker nearer.
    let s = cornered();
    let two_samples = |after_escape: bool| {
        let mut mpc = LinearMpc::new(&s).unwrap();
        // Every program solved, none failed by the proof below, so that the solves
        // count the programs tried.
        mpc.proves_infeasible = false;
        mpc.set_tracks(&exact_tracks(&s, 0.0));
        let escape = mpc.step(0, at_rest(&s), 0.0);
        assert!(escape.is_solved() && mpc.last_escaped, "sample 0 escaped");
        mpc.last_escaped = after_escape;
        mpc.set_tracks(&exact_tracks(&s, s.timing.ts_s));
        mpc.step(1, at_rest(&s), 0.0)
    };
    let (after_escape, retried) = (two_samples(true), two_samples(false));
    assert!(after_escape.is_solved() && retried.is_solved());
    // Neither the relaxed program nor the cold retry found a bounded plan: the same
    // escape, two solves fewer (the relaxed warm program's and the cold retry's; among
    // tracks the cold retry is not relaxed either, `LinearMpc::relaxes`).
    assert_eq!(after_escape.z, retried.z);
    assert_eq!(after_escape.solves + 2, retried.solves);
}

#[test]
fn a_program_whose_terminal_rows_no_input_meets_fails_without_a_solve() {
    // The world of the escape above: the walker's disc, swept over the fastest stop,
    // covers every last position the input box reaches, so the bounded programs are
    // infeasible before clarabel is asked. The step offers the same escape plan with
    // the solves of the escape program alone.
    let s = cornered();
    let step = |proves: bool| {
        let mut mpc = LinearMpc::new(&s).unwrap();
        mpc.proves_infeasible = proves;
        mpc.set_tracks(&exact_tracks(&s, 0.0));
        let plan = mpc.step(0, at_rest(&s), 0.0);
        (plan, mpc.last_escaped)
    };
    let ((proved, escaped), (solved, solved_escaped)) = (step(true), step(false));
    assert!(proved.is_solved() && escaped && solved_escaped);
    assert_eq!(proved.z, solved.z);
    // Without the proof clarabel proves the bounded program infeasible, unrelaxed and
    // relaxed (sample 0 starts cold: no cold retry).
    assert!(
        proved.solves + 2 == solved.solves && proved.iterations < solved.iterations,
        "{} solves and {} iterations against {} and {}",
        proved.solves,
        proved.iterations,
        solved.solves,
        solved.iterations
    );
    // A program the input box can meet is not failed so: the walker far off.
    let mut far = s.clone();
    far.obstacles[0].x = -4.0;
    let mut mpc = LinearMpc::new(&far).unwrap();
    mpc.set_tracks(&exact_tracks(&far, 0.0));
    let plan = mpc.step(0, at_rest(&far), 0.0);
    assert!(plan.is_solved() && !mpc.last_escaped);
}
