//! clarabel for the MPC: the settings of every subproblem, and a solver whose sparsity is
//! built once and whose values are updated every step ([`ConicSolver`]).

use crate::assembly::{Assembly, csc_with_positions};
use clarabel::algebra::CscMatrix;
use clarabel::solver::{DefaultInfo, SolverStatus, SupportedConeT};
use protocol::PlanStatus;
use protocol::task::Cancel;
use std::cell::RefCell;
use std::rc::Rc;

/// What the solves of a step came to: the status of the last, and the interior-point
/// iterations and solves of all of them.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Outcome {
    pub status: PlanStatus,
    pub iterations: u32,
    pub solves: u32,
}

impl Outcome {
    /// The outcome of `retry`, tried after this one, with the work of both.
    pub fn then(self, retry: Outcome) -> Outcome {
        Outcome {
            iterations: self.iterations + retry.iterations,
            solves: self.solves + retry.solves,
            ..retry
        }
    }
}

/// Where a warm-up's cancel check sits while the warm-up runs ([`CancelSlot::during`]):
/// shared by every solver of an MPC and its step, it cuts their solves short between
/// clarabel's interior-point iterations (the termination callback set at the build) and
/// stops a step from trying anything more. A warm-up that runs up to the moment its input
/// comes must not hold up the step it warms up for. Empty, it cancels nothing.
#[derive(Clone, Default)]
pub struct CancelSlot(Rc<RefCell<Option<Cancel>>>);

impl CancelSlot {
    /// Whether a warm-up runs and its cancel check holds.
    pub fn cancelled(&self) -> bool {
        self.0.borrow().as_ref().is_some_and(|cancel| cancel())
    }

    /// Runs `warm_up` with `cancel` in the slot (a clone of the `Rc`: no allocation).
    pub fn during<R>(&self, cancel: &Cancel, warm_up: impl FnOnce() -> R) -> R {
        struct Empties<'a>(&'a CancelSlot);
        impl Drop for Empties<'_> {
            fn drop(&mut self) {
                self.0.0.borrow_mut().take();
            }
        }
        *self.0.borrow_mut() = Some(cancel.clone());
        let _empties = Empties(self);
        warm_up()
    }
}

/// A [`CancelSlot`] in clarabel's termination callback, which clarabel asks to be `Send`
/// and `Sync` though it calls it only within `solve()`, on the thread that solves.
struct OnTheSolvingThread(CancelSlot);

impl OnTheSolvingThread {
    fn cancelled(&self) -> bool {
        self.0.cancelled()
    }
}

// SAFETY: the callback holding this is boxed inside a clarabel solver that only
// `ConicSolver` holds, in a private field it never moves out; `ConicSolver` holds a
// `CancelSlot` itself (an `Rc`), so it is neither `Send` nor `Sync`: the callback is only
// ever called, cloned and dropped on the thread that made it.
unsafe impl Send for OnTheSolvingThread {}
// SAFETY: as for `Send`.
unsafe impl Sync for OnTheSolvingThread {}

/// clarabel's settings for every MPC subproblem: what the accuracy needs and no more
/// (measured with callgrind on the paper run, instructions per MPC step, docs/performance.md): no
/// iterative refinement of the KKT solves (their residual products were half the work),
/// no equilibration (the problem is well scaled), a feasibility tolerance of 1e-6
/// instead of 1e-8 (a micrometre on positions in metres: safety is decided by
/// feasibility), and an absolute duality gap of 1e-3 (optimality only: with `R = 100 I`
/// the inputs are then within `sqrt(2e-3 / 200)`, about 3 mm/s^2, of the optimal ones).
/// The relative gap is 1e-7 so that the absolute one decides: the cost includes the
/// large `z_i'Q z_i` of a robot metres from its goal, and a relative 1e-6 of it would
/// allow inputs ten times further from the optimum. The trajectory of the paper run is
/// the same to the millisecond. A solve that stops short of these (`AlmostSolved`,
/// counted as solved) must still be feasible to 1e-6, with a gap of at most 1e-2.
pub fn solver_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettings {
        tol_gap_abs: 1e-3,
        tol_gap_rel: 1e-7,
        reduced_tol_gap_abs: 1e-2,
        reduced_tol_gap_rel: 1e-6,
        ..base_settings()
    }
}

/// The settings [`solver_settings`] starts from, and the nonlinear baseline's as they
/// are (its SQP's step test needs the tighter gap): no iterative refinement, no
/// equilibration, feasibility to 1e-6 (also when `AlmostSolved`), duality gap 1e-6.
pub fn base_settings() -> clarabel::solver::DefaultSettings<f64> {
    clarabel::solver::DefaultSettings {
        verbose: false,
        iterative_refinement_enable: false,
        equilibrate_enable: false,
        tol_gap_abs: 1e-6,
        tol_gap_rel: 1e-6,
        tol_feas: 1e-6,
        reduced_tol_feas: 1e-6,
        ..clarabel::solver::DefaultSettings::default()
    }
}

/// A clarabel solver for a problem whose sparsity never changes: built from one
/// assembly, afterwards only its values are updated (`update_A`, `update_b`, `update_q`).
///
/// Every program has a careful twin, built with it: clarabel's equilibration and
/// iterative refinement of the KKT solves on (the settings leave both off for speed:
/// docs/performance.md). It solves only when the plain solve stalls (`NumericalError`,
/// `InsufficientProgress`, the primal residual stuck at 1e-6 to 1e-3: seen with the
/// terminal rows where several discs squeeze the plan, and at Ts = 10 ms, where the inputs
/// move the positions of a short horizon by millimetres). Either switch on every solve
/// doubles the paper run's solve time; either alone in the twin left stalls. clarabel
/// equilibrates once, at the build, and re-applies that scaling to every update: the
/// twin's scaling is that of the setup's data, not of the stalled step's (it still
/// finished every stall in the tests and the fuzz batches).
pub struct ConicSolver {
    settings: fn() -> clarabel::solver::DefaultSettings<f64>,
    /// Cuts a solve of a warm-up short.
    cancel: CancelSlot,
    solver: Option<clarabel::solver::DefaultSolver<f64>>,
    careful: Option<clarabel::solver::DefaultSolver<f64>>,
    /// Whether the last solution is the careful twin's.
    careful_last: bool,
    /// Where each [`Assembly`] entry sits in the CSC values.
    nz_position: Vec<usize>,
    nzval: Vec<f64>,
}

impl ConicSolver {
    /// A solver of `settings` whose solves `cancel` cuts short.
    pub fn new(
        settings: fn() -> clarabel::solver::DefaultSettings<f64>,
        cancel: CancelSlot,
    ) -> ConicSolver {
        ConicSolver {
            settings,
            cancel,
            solver: None,
            careful: None,
            careful_last: false,
            nz_position: Vec::new(),
            nzval: Vec::new(),
        }
    }

    /// Solves the problem of `assembly` (the pattern it was built with), on the careful
    /// twin if the plain solve stalls. Returns the plan status and the
    /// interior-point iterations of both.
    pub fn solve(&mut self, assembly: &Assembly) -> (protocol::PlanStatus, u32) {
        use clarabel::solver::SolverStatus;
        self.careful_last = false;
        if self.cancel.cancelled() {
            return (protocol::PlanStatus::NumericalError, 0);
        }
        for (t, &(_, _, v)) in assembly.entries.iter().enumerate() {
            self.nzval[self.nz_position[t]] = v;
        }
        let Some((status, mut iterations)) = solve_with(&mut self.solver, &self.nzval, assembly)
        else {
            return (protocol::PlanStatus::NumericalError, 0);
        };
        let mut status = status;
        if matches!(
            status,
            SolverStatus::NumericalError | SolverStatus::InsufficientProgress
        ) && let Some((twin, twin_iterations)) =
            solve_with(&mut self.careful, &self.nzval, assembly)
        {
            self.careful_last = true;
            (status, iterations) = (twin, iterations + twin_iterations);
        }
        (plan_status(status), iterations)
    }

    /// Builds the solver (and its careful twin) for the pattern of `assembly` (kept
    /// from then on) and runs one interior-point iteration of a solve, so that clarabel's
    /// bookkeeping is in place before the next solve ([`timers_kept_between_solves`]).
    /// False if clarabel refuses the data.
    pub fn build(
        &mut self,
        assembly: &Assembly,
        variables: usize,
        objective: &CscMatrix<f64>,
        cones: &[SupportedConeT<f64>],
    ) -> bool {
        let (a, positions) = csc_with_positions(assembly.b.len(), variables, &assembly.entries);
        self.nzval = a.nzval.clone();
        self.nz_position = positions;
        let q = if assembly.q.is_empty() {
            vec![0.0; variables]
        } else {
            assembly.q.clone()
        };
        let built = |settings: clarabel::solver::DefaultSettings<f64>| {
            debug_assert!(
                settings.time_limit.is_infinite(),
                "clarabel's clock runs from the build (timers_kept_between_solves)"
            );
            let solver = clarabel::solver::DefaultSolver::new(
                objective,
                &q,
                &a,
                &assembly.b,
                cones,
                settings,
            );
            solver.ok().map(|mut solver| {
                use clarabel::solver::IPSolver;
                // One iteration runs every part of a solve (and allocates what it
                // needs): the build's solve stops there, a program of the MPC's dozens
                // built at setup costs two factorizations (the starting point's and the
                // iteration's), not a whole solve's.
                solver.set_termination_callback(|info: &DefaultInfo<f64>| info.iterations >= 1);
                solver.timers = Some(timers_kept_between_solves());
                solver.solve();
                let cancel = OnTheSolvingThread(self.cancel.clone());
                solver.set_termination_callback(move |_| cancel.cancelled());
                solver
            })
        };
        self.solver = built((self.settings)());
        self.careful = built(clarabel::solver::DefaultSettings {
            equilibrate_enable: true,
            iterative_refinement_enable: true,
            ..(self.settings)()
        });
        self.solver.is_some() && self.careful.is_some()
    }

    pub fn is_built(&self) -> bool {
        self.solver.is_some()
    }

    /// Solves the last problem again, for its memory's sake: a process that slept since its
    /// last step finds the solver's working set (KKT matrix, factors, iterates) in cache at
    /// its next one. It changes nothing that step sees: the step writes its own data first
    /// and clarabel starts every solve afresh from the data; the solution is read only
    /// after a step's own solve ([`ConicSolver::x`]). Returns the interior-point
    /// iterations (fewer when its [`CancelSlot`] cuts it short).
    pub fn solve_again(&mut self) -> u32 {
        use clarabel::solver::IPSolver;
        self.solver.as_mut().map_or(0, |solver| {
            solver.solve();
            solver.solution.iterations
        })
    }

    /// The last solution's variables (none before the first solve).
    pub fn x(&self) -> Option<&[f64]> {
        let last = if self.careful_last {
            &self.careful
        } else {
            &self.solver
        };
        last.as_ref().map(|s| s.solution.x.as_slice())
    }
}

/// Writes the values (`nzval` of `A`, and `b`, `q` of `assembly`) into `solver` and solves;
/// `None` if it is not built or refuses them.
#[allow(clippy::ptr_arg)] // clarabel's `update_A` takes a `Vec`, not a slice (it needs `Sized`)
fn solve_with(
    solver: &mut Option<clarabel::solver::DefaultSolver<f64>>,
    nzval: &Vec<f64>,
    assembly: &Assembly,
) -> Option<(clarabel::solver::SolverStatus, u32)> {
    use clarabel::solver::IPSolver;
    let solver = solver.as_mut()?;
    solver
        .update_A(nzval)
        .and_then(|()| solver.update_b(&assembly.b))
        .and_then(|()| {
            if assembly.q.is_empty() {
                Ok(())
            } else {
                solver.update_q(&assembly.q)
            }
        })
        .ok()?;
    solver.solve();
    Some((solver.solution.status, solver.solution.iterations))
}

/// clarabel's timers, arranged so that `solve()` allocates nothing once it has run once.
///
/// clarabel 0.11 starts every `solve()` by resetting its root-level "solve" timer, which
/// drops the timers nested in it with their hash maps and rebuilds them during the solve:
/// heap allocations in every solve, with no setting to turn timing off. Here a frame
/// timer is left open around the solver's own timers, so "solve" and everything under it
/// nest inside the frame and survive; the reset then hits an empty root-level "solve".
/// The cost: clarabel's `info.solve_time` becomes the wall time since the build, which
/// would trip any finite `time_limit` (none is set: `build` checks it in debug builds);
/// this crate times its steps itself.
fn timers_kept_between_solves() -> clarabel::timers::Timers {
    let mut timers = clarabel::timers::Timers::default();
    timers.start_as_current("scmpc frame");
    timers
}

/// The plan status of a clarabel status.
pub fn plan_status(status: SolverStatus) -> PlanStatus {
    match status {
        SolverStatus::Solved | SolverStatus::AlmostSolved => PlanStatus::Solved,
        SolverStatus::PrimalInfeasible
        | SolverStatus::AlmostPrimalInfeasible
        | SolverStatus::DualInfeasible
        | SolverStatus::AlmostDualInfeasible => PlanStatus::Infeasible,
        SolverStatus::MaxIterations | SolverStatus::MaxTime => PlanStatus::MaxIterations,
        _ => PlanStatus::NumericalError,
    }
}
