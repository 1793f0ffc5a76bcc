//! After the first 20 samples, no role's step performs a heap allocation, to the end of
//! the run: a counting global allocator around each role's pass of the in-process closed loop
//! (`ClosedLoop`, the one `scmpc run --in-process` steps), for every solver program and
//! every fallback. For the MPC this includes every clarabel `solve()` and the faults; a
//! role's pass includes handing what it gave to its consumers. The real-time MPC's warm-up
//! (`Mpc::warm_up`) is counted with the steps it comes before.

use protocol::{CommandMode, Scenario};
use run::closed_loop::ClosedLoop;
use runtime::alloc_count::{Counting, allocations as allocated};

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f`. (The test harness runs other tests on other threads, so this
/// file holds a single test.)
fn allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let before = allocated();
    let out = f();
    (out, allocated() - before)
}

/// Roles counted apart, by their codes: plant, estimator, MPC, DFL, planner, tracker,
/// odometer, lidar.
const ROLES: usize = protocol::Role::COUNT;

/// Steps `scenario` to its end in process, each role's pass under the allocation counter;
/// returns the allocations after the first 20 samples by role code ([`ROLES`]), and the
/// command modes the DFL used after them.
fn count_whole_run(scenario: &protocol::Validated) -> ([u64; ROLES], Vec<CommandMode>) {
    let mut closed_loop = ClosedLoop::new(scenario).unwrap();
    // Warm-up: the first samples size every buffer.
    let warm_up = scenario.timing.first_tick(20);
    let mut counts = [0u64; ROLES];
    let mut modes = Vec::new();
    while !closed_loop.is_done() {
        let counting = closed_loop.tick() >= warm_up;
        let mut by_role = [0u64; ROLES];
        let tick = closed_loop
            .step_each(|role, pass| by_role[role as usize] += allocations(pass).1)
            .expect("no fault refuses a message here");
        if counting {
            for (c, a) in counts.iter_mut().zip(by_role) {
                *c += a;
            }
            if let Some(mode) = tick.actuation.mode().filter(|m| !modes.contains(m)) {
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
            counts, [0; ROLES],
            "{formulation} {qp_form}: allocations after warm-up by role code"
        );
    }
    // The route planner and the MPC following its route, through an obstacle field
    // (replans by period, stall or stray included), both programs.
    for qp_form in ["sparse", "condensed"] {
        let field =
            run::scenarios::load(Some("field"), &[format!("mpc.qp_form={qp_form}")]).unwrap();
        let (counts, _) = count_whole_run(&field);
        assert_eq!(
            counts, [0; ROLES],
            "field, {qp_form}: allocations after warm-up by role code"
        );
    }
    // A base with a lag and a command delay: the plant's line of commands, the estimator's
    // and the DFL's models of the base, and people on the way (tracks shifted by the lead).
    let lagged = run::scenarios::load(
        Some("crossing"),
        &[
            "robot.actuator_lag_s=0.05".into(),
            "robot.command_delay_s=0.02".into(),
        ],
    )
    .unwrap();
    let (counts, _) = count_whole_run(&lagged);
    assert_eq!(
        counts, [0; ROLES],
        "a lagged, delayed base: allocations after warm-up by role code"
    );
    // Seeing with a lidar: the lidar's scans, the tracker's perception (groups, discs, the
    // assignment, tracks, phantoms) and the MPC and the DFL keeping clear of what it sees.
    for world in ["unmapped", "occluded"] {
        let (counts, _) = count_whole_run(&run::scenarios::load(Some(world), &[]).unwrap());
        assert_eq!(
            counts, [0; ROLES],
            "{world}: allocations after warm-up by role code"
        );
    }
    // Stepping out of a person's way (`dfl::evasion`): the lidar fuzz's world 372 of seed
    // 1, where the robot, braked without a plan, searches its evasions and flies one.
    let world = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/fuzz-lidar-seed-1-world-372.toml"
    );
    let (counts, modes) = count_whole_run(&run::scenarios::load(Some(world), &[]).unwrap());
    assert!(modes.contains(&CommandMode::Evasion), "{modes:?}");
    assert_eq!(
        counts, [0; ROLES],
        "world 372: allocations after warm-up by role code"
    );
    // The real-time MPC's warm-up before each sample (a dry step, then its state put
    // back), in both programs: the robot follows each plan's first state, off by a drift.
    // Whole, then cut short as the estimate's arrival cuts it: the cancel check holds from
    // its `k % fewest`-th call on, `fewest` the fewest checks a whole rehearsal made, so
    // that every cut falls inside its rehearsal (anywhere, or at once).
    for qp_form in ["sparse", "condensed"] {
        let scenario = scenario(&[&format!("mpc.qp_form={qp_form}")]);
        let whole = rehearse(&scenario, |_| u64::MAX);
        assert_eq!(whole.allocations, 0, "{qp_form}: whole warm-ups and steps");
        let fewest = *whole.checks.iter().min().unwrap();
        assert!(
            fewest >= 2,
            "{qp_form}: a whole rehearsal asked {fewest} times"
        );
        let cut = rehearse(&scenario, |k| k % fewest);
        assert_eq!(
            cut.allocations, 0,
            "{qp_form}: warm-ups cut short and steps"
        );
        // Each rehearsal was cut where it says: asked once past its cut (the answer that
        // cut it) and stopped, asking at most twice more (the solver's callback, the
        // refinement's check) before the step.
        for (k, &checks) in (20..).zip(&cut.checks) {
            let cut_at = k % fewest;
            assert!(
                (cut_at + 1..=cut_at + 3).contains(&checks),
                "{qp_form}: sample {k} cut at check {cut_at} asked {checks} times"
            );
        }
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
            counts, [0; ROLES],
            "{overrides:?}: allocations after warm-up by role code"
        );
    }
}

/// What [`rehearse`] saw after the first 20 samples.
struct Rehearsals {
    /// Allocations in the warm-ups and steps.
    allocations: u64,
    /// How often each warm-up and step asked whether to stop.
    checks: Vec<u64>,
}

/// Steps the MPC of `scenario` 300 times, each step after a warm-up (`Mpc::warm_up`)
/// whose cancel check holds from its `cut_at(k)`-th call on; the robot follows each plan's
/// first state, off by a drift.
fn rehearse(scenario: &protocol::Validated, cut_at: impl Fn(u64) -> u64) -> Rehearsals {
    use std::cell::Cell;
    use std::rc::Rc;
    let mut mpc = mpc::Mpc::new(scenario).unwrap();
    let [x, y, theta] = scenario.robot.start;
    let mut x_bar = [x, y, theta, scenario.robot.zeta0];
    let (checks, cut) = (Rc::new(Cell::new(0u64)), Rc::new(Cell::new(u64::MAX)));
    let cancel: protocol::task::Cancel = {
        let (checks, cut) = (checks.clone(), cut.clone());
        Rc::new(move || {
            checks.set(checks.get() + 1);
            checks.get() > cut.get()
        })
    };
    let mut seen = Rehearsals {
        allocations: 0,
        checks: Vec::new(),
    };
    for k in 0..300 {
        checks.set(0);
        cut.set(cut_at(k));
        let (plan, a) = allocations(|| {
            mpc.warm_up(u64::MAX, &cancel);
            mpc.step(k, x_bar, 0.01)
        });
        if k >= 20 {
            seen.allocations += a;
            seen.checks.push(checks.get());
        }
        let drift = 0.003 * (k as f64).sin();
        x_bar = protocol::phi_inverse(plan.z[1], x_bar[2]);
        x_bar[0] += drift;
    }
    seen
}
