//! The step functions of the four roles, each on the states of the paper's closed loop:
//! `cargo bench --bench steps`.

use dfl::Dfl;
use estimator::Estimator;
use mpc::Mpc;
use plant::Plant;
use protocol::{Estimate, Header, Obstacle, Plan, Scenario};
use run::closed_loop::ClosedLoop;

fn main() {
    divan::main();
}

/// The estimates (per tick) and plans (per sample) of the in-process closed loop of
/// `scenario`, the loop `scmpc run --in-process` steps.
fn closed_loop(scenario: &Scenario) -> (Vec<Estimate>, Vec<Plan>) {
    let scenario = scenario.clone().validated("bench").expect("valid scenario");
    let mut closed_loop = ClosedLoop::new(&scenario).expect("MPC set up");
    let (mut estimates, mut plans) = (Vec::new(), Vec::new());
    while let Some(Ok(tick)) = (!closed_loop.is_done()).then(|| closed_loop.step()) {
        estimates.push(tick.estimate);
        plans.extend(tick.plan);
    }
    (estimates, plans)
}

/// One MPC step per iteration, walking the closed loop's states in order (warm starts as
/// in a run), from the start again at the end. Divan's samples of one iteration each
/// are the steps' own times.
fn bench_mpc(bencher: divan::Bencher, scenario: &Scenario) {
    let (estimates, _) = closed_loop(scenario);
    let estimates: Vec<Estimate> = estimates
        .into_iter()
        .step_by(scenario.timing.inner_steps)
        .collect();
    let mut mpc = Mpc::new(scenario).expect("valid scenario");
    let mut k = 0;
    bencher.bench_local(|| {
        if k == estimates.len() {
            k = 0;
            mpc.reset();
        }
        let e = &estimates[k];
        let plan = mpc.step(k as u64, e.state, e.position_sigma());
        k += 1;
        plan
    });
}

/// Samples of a 30 s run: every benchmark of the MPC covers the whole closed loop.
const RUN_SAMPLES: u32 = 600;

#[divan::bench(args = [8, 30], sample_count = RUN_SAMPLES)]
fn mpc_step(bencher: divan::Bencher, horizon: usize) {
    let mut s = Scenario::paper();
    s.mpc.horizon = horizon;
    bench_mpc(bencher, &s);
}

/// The paper's formulation (`mpc.terminal_safety = "none"`, and its closed loop without
/// the DFL's safety check), to compare with `mpc_step`.
#[divan::bench(sample_count = RUN_SAMPLES)]
fn mpc_step_paper_formulation(bencher: divan::Bencher) {
    bench_mpc(bencher, &paper_formulation());
}

/// The paper's scenario without the safety layers added to the paper's scheme.
fn paper_formulation() -> Scenario {
    Scenario::paper()
        .with_overrides(&[
            "mpc.terminal_safety=none".into(),
            "dfl.gatekeeper=false".into(),
        ])
        .expect("valid overrides")
}

/// The form `auto` does not pick for the horizon (`mpc.qp_form`): sparse at N = 8,
/// condensed at N = 30.
#[divan::bench(args = [8, 30], sample_count = RUN_SAMPLES)]
fn mpc_step_other_qp_form(bencher: divan::Bencher, horizon: usize) {
    let mut s = Scenario::paper();
    s.mpc.horizon = horizon;
    s.mpc.qp_form = if protocol::QpForm::Auto.condensed(horizon) {
        protocol::QpForm::Sparse
    } else {
        protocol::QpForm::Condensed
    };
    bench_mpc(bencher, &s);
}

#[divan::bench(sample_count = RUN_SAMPLES)]
fn mpc_step_five_obstacles(bencher: divan::Bencher) {
    let mut s = Scenario::paper();
    s.obstacles.extend([
        Obstacle::fixed(-3.0, 2.0, 0.5),
        Obstacle::fixed(6.0, -3.0, 0.8),
        Obstacle::fixed(-5.0, -5.0, 1.0),
        Obstacle::fixed(1.0, 7.5, 0.6),
    ]);
    bench_mpc(bencher, &s);
}

#[divan::bench(sample_count = RUN_SAMPLES)]
fn nonlinear_mpc_step(bencher: divan::Bencher) {
    let mut s = Scenario::paper();
    s.mpc.formulation = protocol::Formulation::Nonlinear;
    s.mpc.terminal_safety = protocol::TerminalSafety::None;
    bench_mpc(bencher, &s);
}

/// One DFL tick per iteration, walking the closed loop's ticks in order with each plan
/// offered at its sample's first tick, as in a run (with the safety check: a commit
/// check then, a re-check of the committed trajectory on every tick).
fn bench_dfl(bencher: divan::Bencher, scenario: &Scenario) {
    let (estimates, plans) = closed_loop(scenario);
    let timing = &scenario.timing;
    let mut dfl = Dfl::new(scenario);
    let mut tick = 0;
    bencher.bench_local(|| {
        if tick == estimates.len() {
            tick = 0;
            dfl = Dfl::new(scenario);
        }
        if timing.starts_sample(tick as u64) {
            dfl.offer(&plans[timing.sample_of(tick as u64) as usize]);
        }
        let act = dfl.step(&estimates[tick], tick as u64);
        tick += 1;
        act
    });
}

#[divan::bench]
fn dfl_step(bencher: divan::Bencher) {
    bench_dfl(bencher, &Scenario::paper());
}

#[divan::bench]
fn dfl_step_without_safety_check(bencher: divan::Bencher) {
    bench_dfl(bencher, &paper_formulation());
}

/// The DFL's tick that searches every evasion and finds none (docs/safety.md, "Stepping
/// out of the way"), its most costly: a robot at rest at the origin on its way along x, a
/// person 0.5 m behind it walking at it at 1 m/s (along its heading, so no evasion gets
/// away), and 9 more tracks 4 m away; every candidate is looked ahead 1 s.
#[divan::bench]
fn dfl_step_searching_evasions(bencher: divan::Bencher) {
    let mut s = Scenario {
        obstacles: vec![Obstacle {
            velocity: [1.0, 0.0],
            ..Obstacle::fixed(-0.8, 0.0, 0.3)
        }],
        ..Scenario::default()
    };
    s.robot.goal.position = [5.0, 0.0];
    let mut tracks = protocol::Tracks {
        count: 10,
        ..protocol::Tracks::default()
    };
    for (i, track) in tracks.tracks[..10].iter_mut().enumerate() {
        let angle = i as f64 * 0.6;
        *track = protocol::Track {
            obstacle: i as u32,
            radius_m: 0.3,
            center: if i == 0 {
                [-0.8, 0.0]
            } else {
                [4.0 * angle.cos(), 4.0 * angle.sin()]
            },
            velocity: if i == 0 { [1.0, 0.0] } else { [0.0, 0.0] },
            covariance: [1e-4, 0.0, 1e-4, 1e-4, 0.0, 1e-4],
            ..protocol::Track::default()
        };
    }
    let mut dfl = Dfl::new(&s);
    dfl.set_tracks(&tracks);
    let at_rest = Estimate::default();
    let first = dfl.step(&at_rest, 0);
    assert_eq!(
        first.mode(),
        Some(protocol::CommandMode::Brake),
        "an evasion was found"
    );
    bencher.bench_local(|| dfl.step(&at_rest, 0));
}

#[divan::bench]
fn ekf_step(bencher: divan::Bencher) {
    let s = Scenario::paper()
        .with_overrides(&["plant.noise_variance=0.05".into()])
        .expect("valid override");
    let mut plant = Plant::new(&s);
    let mut estimator = Estimator::new(&s);
    let dt = s.timing.dt_s();
    let mut tick = 0;
    bencher.bench_local(|| {
        tick += 1;
        let header = Header {
            tick,
            ..Header::default()
        };
        estimator.step(Some([0.5, 0.1]), dt, plant.measure(), 0.5, header)
    });
}

#[divan::bench]
fn plant_step(bencher: divan::Bencher) {
    let s = Scenario::paper();
    let mut plant = Plant::new(&s);
    let dt = s.timing.dt_s();
    bencher.bench_local(|| plant.step(0.5, 0.1, dt));
}

/// One route search ([`planner::TangentGraph::shortest_path`]) per iteration, over 1000
/// random fields of `n` discs in turn (`study::bench::planning_field`): the median
/// is the median field's (`scmpc bench` reports p50 and p99).
#[divan::bench(args = [5, 20], sample_count = 1000)]
fn route_planning(bencher: divan::Bencher, n: usize) {
    use study::bench::{PLANNING_FIELDS, PLANNING_START, planning_field};
    let fields: Vec<Vec<planner::Disc>> = (0..PLANNING_FIELDS)
        .map(|seed| planning_field(seed, n))
        .collect();
    let mut graph = planner::TangentGraph::with_capacity(n);
    let mut k = 0;
    bencher.bench_local(|| {
        let discs = &fields[k % fields.len()];
        k += 1;
        graph
            .shortest_path(
                PLANNING_START,
                [0.0, 0.0],
                discs,
                [[-10.0, 10.0], [-10.0, 10.0]],
            )
            .is_ok()
    });
}

/// One perception step per iteration ([`tracker::Perception::take`]): 360 beams all
/// around, 10 obstacles not in the map (five people walking, five boxes) at 1 to 6 m, so
/// about 10 groups and 10 tracks, with the phantoms of their shadows; 200 scans at 10 Hz,
/// walked in order and from the start again.
#[divan::bench(sample_count = 2000)]
fn perception_step(bencher: divan::Bencher) {
    use rand_chacha::rand_core::SeedableRng;
    let mut s = Scenario::paper();
    s.lidar = Some(protocol::LidarConfig::default());
    s.obstacles = (0..10)
        .map(|i| {
            let bearing = f64::from(i) * std::f64::consts::TAU / 10.0;
            let range = 1.0 + 0.5 * f64::from(i);
            let velocity = if i % 2 == 0 {
                [0.0, 0.0]
            } else {
                [-0.3 * bearing.sin(), 0.3 * bearing.cos()]
            };
            Obstacle {
                velocity,
                known: Some(false),
                ..Obstacle::fixed(range * bearing.cos(), range * bearing.sin(), 0.3)
            }
        })
        .collect();
    let s = s.validated("bench").expect("valid scenario");
    let config = s.lidar.clone().expect("a lidar");
    let sensor = lidar::Lidar::of(&config);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let scans: Vec<protocol::Scan> = (0..200u32)
        .map(|k| {
            let time_s = f64::from(k) / config.rate_hz;
            let discs: Vec<lidar::Disc> = (s.obstacles.iter())
                .map(|o| (o.center_at(time_s), o.radius))
                .collect();
            let header = Header {
                tick: k.into(),
                time_s,
                ..Header::default()
            };
            sensor.scan_message(header, [0.0; 3], &discs, &mut rng)
        })
        .collect();
    let mut perception = tracker::Perception::new(&s);
    let mut k = 0;
    bencher.bench_local(|| {
        if k == scans.len() {
            k = 0;
            perception = tracker::Perception::new(&s);
        }
        perception.take(&scans[k], [0.0; 3], &[]);
        k += 1;
    });
}
