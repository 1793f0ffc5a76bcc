//! The steady state of every role's step performs no heap allocation: a counting global
//! allocator around each call of the role libraries, on the paper scenario's closed loop.
//! For the MPC this includes every clarabel `solve()`.

use dfl::{DeadlineMonitor, Dfl, PlanInbox};
use estimator::Estimator;
use mpc::Mpc;
use plant::Plant;
use protocol::{Header, Scenario};
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
            .unwrap();
        scenario.validate("test").unwrap();
        let m = scenario.timing.inner_steps as u64;
        let dt = scenario.timing.ts_s / m as f64;
        let mut plant = Plant::new(&scenario);
        let mut estimator = Estimator::new(&scenario);
        let mut mpc = Mpc::new(&scenario).unwrap();
        let mut dfl = Dfl::new(&scenario);
        let mut inbox = PlanInbox::new(true, scenario.timing.ts_s);
        let mut monitor = DeadlineMonitor::new(scenario.timing.ts_s);
        let mut applied = None;
        // Warm-up: the first samples size every buffer.
        let warm_up = 20 * m;
        let mut counts = [0u64; 4];
        for tick in 0..60 * m {
            let header = Header {
                tick,
                time_s: tick as f64 * dt,
                ..Header::default()
            };
            let (y, plant_a) = allocations(|| plant.measure());
            let (estimate, est_a) =
                allocations(|| estimator.step(applied, dt, y, dfl.zeta(), header));
            let (mut mpc_a, mut inbox_a) = (0, 0);
            if tick.is_multiple_of(m) {
                let (plan, a) =
                    allocations(|| mpc.step(tick / m, estimate.state, estimate.position_sigma()));
                mpc_a = a;
                assert!(
                    plan.is_solved(),
                    "{formulation} {qp_form}: sample {} not solved",
                    tick / m
                );
                ((), inbox_a) = allocations(|| {
                    inbox.receive(&plan);
                    monitor.on_plan(&plan, 0);
                });
            }
            let (act, dfl_a) = allocations(|| {
                inbox.release(tick / m, &mut dfl);
                let act = dfl.step(&estimate, tick);
                if let Some(mode) = act.mode().filter(|_| tick.is_multiple_of(m)) {
                    monitor.sample_started(tick / m, mode);
                }
                act
            });
            let (_, step_a) = allocations(|| plant.step(act.u1, act.u2, dt));
            applied = Some([act.u1, act.u2]);
            if tick >= warm_up {
                let by_role = [plant_a + step_a, est_a, mpc_a, inbox_a + dfl_a];
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
