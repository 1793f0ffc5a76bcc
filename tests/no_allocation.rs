//! The steady state of every role's step performs no heap allocation: a counting global
//! allocator around each phase of the in-process closed loop (`ClosedLoop`, the one
//! `scmpc run --in-process` steps), on the paper scenario with noise. For the MPC this
//! includes every clarabel `solve()`; the plan phase includes the faults and the inbox.

use orchestrator::closed_loop::ClosedLoop;
use protocol::Scenario;
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicU64, Ordering};

/// The system allocator, counting allocations (and reallocations).
struct Counting;

static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

// SAFETY: forwards to the system allocator unchanged.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f`. (The test harness runs other tests on other threads, so this
/// file holds a single test.)
fn allocations<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    let out = f();
    (out, ALLOCATIONS.load(Ordering::Relaxed) - before)
}

#[test]
fn every_role_step_runs_without_heap_allocation_in_steady_state() {
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
        let scenario = Scenario::default()
            .with_overrides(&[
                format!("mpc.formulation={formulation}"),
                format!("mpc.qp_form={qp_form}"),
                format!("mpc.terminal_safety={terminal_safety}"),
                "plant.noise_variance=0.05".into(),
            ])
            .unwrap()
            .validated("test")
            .unwrap();
        let m = scenario.timing.inner_steps as u64;
        let mut closed_loop = ClosedLoop::new(&scenario).unwrap();
        // Warm-up: the first samples size every buffer.
        let warm_up = 20 * m;
        let mut counts = [0u64; 4];
        while closed_loop.tick() < 60 * m {
            let tick = closed_loop.tick();
            let ((_, y), measure_a) = allocations(|| closed_loop.measure());
            let (estimate, estimate_a) = allocations(|| closed_loop.estimate(y));
            let (plan, plan_a) = allocations(|| closed_loop.plan(&estimate));
            if let Some(plan) = plan {
                assert!(
                    plan.is_solved(),
                    "{formulation} {qp_form}: sample {} not solved",
                    tick / m
                );
            }
            let ((actuation, _), command_a) = allocations(|| closed_loop.command(&estimate));
            let ((), integrate_a) = allocations(|| closed_loop.integrate(&actuation));
            if tick >= warm_up {
                let by_role = [measure_a + integrate_a, estimate_a, plan_a, command_a];
                for (c, a) in counts.iter_mut().zip(by_role) {
                    *c += a;
                }
            }
        }
        assert_eq!(
            counts, [0; 4],
            "{formulation} {qp_form}: allocations after warm-up by plant, estimator, MPC, DFL"
        );
    }
}
