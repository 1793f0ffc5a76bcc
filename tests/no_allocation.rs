//! After the first 20 samples, no role's step performs a heap allocation, to the end of
//! the run: a counting global allocator around each phase of the in-process closed loop
//! (`ClosedLoop`, the one `scmpc run --in-process` steps), for every solver program and
//! every fallback. For the MPC this includes every clarabel `solve()`; the plan phase
//! includes the faults and the inbox. The real-time MPC's rehearsal (`Mpc::rehearse`) is
//! counted with the steps it comes before.

use orchestrator::closed_loop::ClosedLoop;
use protocol::alloc_count::{Counting, allocations as allocated};
use protocol::{CommandMode, Scenario};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f`. (The test harness runs other tests on other threads, so this
/// file holds a single test.)
fn allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let before = allocated();
    let out = f();
    (out, allocated() - before)
}

/// Steps `scenario` to its end in process, each phase under the allocation counter;
/// returns the allocations after the first 20 samples by plant, estimator, MPC and DFL,
/// and the command modes the DFL used after them.
fn count_whole_run(scenario: &protocol::Validated) -> ([u64; 5], Vec<CommandMode>) {
    let mut closed_loop = ClosedLoop::new(scenario).unwrap();
    // Warm-up: the first samples size every buffer.
    let warm_up = scenario.timing.first_tick(20);
    let mut counts = [0u64; 5];
    let mut modes = Vec::new();
    while !closed_loop.is_done() {
        let tick = closed_loop.tick();
        let ((_, y), measure_a) = allocations(|| closed_loop.measure());
        let (estimate, estimate_a) = allocations(|| closed_loop.estimate(y));
        let (estimate, _) = estimate.expect("no fault refuses an estimate here");
        let (_, plan_a) = allocations(|| closed_loop.plan(&estimate));
        let (_, route_a) = allocations(|| closed_loop.route(&estimate));
        let ((actuation, _), command_a) = allocations(|| closed_loop.command(&estimate));
        let ((), integrate_a) = allocations(|| closed_loop.integrate(&actuation));
        if tick >= warm_up {
            let by_role = [
                measure_a + integrate_a,
                estimate_a,
                plan_a,
                command_a,
                route_a,
            ];
            for (c, a) in counts.iter_mut().zip(by_role) {
                *c += a;
            }
            if let Some(mode) = actuation.mode().filter(|m| !modes.contains(m)) {
                modes.push(mode);
            }
        }
    }
    (counts, modes)
}

fn scenario(overrides: &[&str]) -> protocol::Validated {
    let overrides: Vec<String> = overrides.iter().map(|o| o.to_string()).collect();
    Scenario::default()
        .with_overrides(&overrides)
        .unwrap()
        .validated("test")
        .unwrap()
}

#[test]
fn every_role_step_runs_without_heap_allocation_over_whole_runs_fallbacks_included() {
    // Every solver program, to the end of the run (the obstacle pass, the refinement
    // solves and the goal included).
    for (formulation, qp_form) in [
        ("linear", "sparse"),
        ("linear", "condensed"),
        ("nonlinear", "auto"),
    ] {
        // The nonlinear baseline has no terminal safety rows.
        let terminal_safety = if formulation == "linear" {
            "brake"
        } else {
            "none"
        };
        let (counts, _) = count_whole_run(&scenario(&[
            &format!("mpc.formulation={formulation}"),
            &format!("mpc.qp_form={qp_form}"),
            &format!("mpc.terminal_safety={terminal_safety}"),
            "plant.noise_variance=0.05",
        ]));
        assert_eq!(
            counts, [0; 5],
            "{formulation} {qp_form}: allocations after warm-up by plant, estimator, MPC, DFL, planner"
        );
    }
    // The route planner and the MPC following its route, through an obstacle field
    // (replans by period, stall or stray included), both programs.
    for qp_form in ["sparse", "condensed"] {
        let field =
            orchestrator::scenarios::load(Some("field"), &[format!("mpc.qp_form={qp_form}")])
                .unwrap();
        let (counts, _) = count_whole_run(&field);
        assert_eq!(
            counts, [0; 5],
            "field, {qp_form}: allocations after warm-up by plant, estimator, MPC, DFL, planner"
        );
    }
    // The real-time MPC's rehearsal before each sample (a dry step, then its state put
    // back), in both programs: the robot follows each plan's first state, off by a drift.
    for qp_form in ["sparse", "condensed"] {
        let scenario = scenario(&[&format!("mpc.qp_form={qp_form}")]);
        let mut mpc = mpc::Mpc::new(&scenario).unwrap();
        let [x, y, theta] = scenario.robot.start;
        let mut x_bar = [x, y, theta, scenario.robot.zeta0];
        let mut counted = 0;
        for k in 0..300 {
            let (plan, a) = allocations(|| {
                mpc.rehearse(u64::MAX);
                mpc.step(k, x_bar, 0.01)
            });
            if k >= 20 {
                counted += a;
            }
            let drift = 0.003 * (k as f64).sin();
            x_bar = protocol::phi_inverse(plan.z[1], x_bar[2]);
            x_bar[0] += drift;
        }
        assert_eq!(
            counted, 0,
            "{qp_form}: allocations in rehearsals and steps after 20"
        );
    }
    // Every fallback: failed solves (the cold retry, then the shifted plan and braking),
    // late plans, and the gatekeeper refusing the plans of an MPC that ignores obstacles
    // (the committed plan flown, then braking).
    let faults: [(&[&str], &[CommandMode]); 2] = [
        (
            &[
                "fault.mpc_fail_samples=[40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51]",
                "fault.mpc_delay_ms=70",
                "fault.mpc_delay_samples=[80, 90]",
            ],
            &[CommandMode::Shifted, CommandMode::Brake],
        ),
        (
            &["fault.mpc_ignore_obstacles=true"],
            &[CommandMode::Shifted, CommandMode::Brake],
        ),
    ];
    for (overrides, expected) in faults {
        let (counts, modes) = count_whole_run(&scenario(overrides));
        for mode in expected {
            assert!(
                modes.contains(mode),
                "{overrides:?}: no {mode:?} in {modes:?}"
            );
        }
        assert_eq!(
            counts, [0; 5],
            "{overrides:?}: allocations after warm-up by plant, estimator, MPC, DFL, planner"
        );
    }
}
