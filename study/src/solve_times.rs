//! The MPC's solve time in both formulations, the paper's linear scheme against the
//! nonlinear baseline, on the states of one closed loop (`scmpc figures`).

use anyhow::Context;
use protocol::{Formulation, Validated};
use record::Percentiles;
use run::inprocess;
use run::sinks::Recording;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

/// Solve times of both formulations over the same states: the states the linear scheme's
/// closed loop visits (at every sample), solved in sequence by one controller of each
/// formulation (both warm-started from their previous plan), the two solves of a state
/// one right after the other so that load on the machine weighs on both alike, µs.
#[derive(Debug, Clone, PartialEq)]
pub struct SolveTimes {
    pub horizon: usize,
    pub linear_us: Percentiles,
    pub nonlinear_us: Percentiles,
    /// Nonlinear plans that were not `solved`.
    pub nonlinear_failures: usize,
}

/// [`SolveTimes`] at horizon `horizon` of `base` (its closed loop run in process into
/// `dir`); interrupted between two solves once `stop` is set.
pub fn compare_solve_times(
    base: &Validated,
    horizon: usize,
    dir: &Path,
    stop: &AtomicBool,
) -> anyhow::Result<SolveTimes> {
    let sets = [
        format!("mpc.horizon={horizon}"),
        "mpc.formulation=linear".to_string(),
    ];
    let scenario = base.with_overrides(&sets, &format!("horizon {horizon}"))?;
    let states = closed_loop_states(&scenario, dir, stop)?;
    run::stop::check(stop)?;
    let controller = |formulation: Formulation| {
        let mut s = (*scenario).clone();
        s.mpc.formulation = formulation;
        mpc::Mpc::new(&s).context("setting up the MPC")
    };
    let (mut lin, mut nonlin) = (
        controller(Formulation::Linear)?,
        controller(Formulation::Nonlinear)?,
    );
    let mut linear = Vec::with_capacity(states.len());
    let mut nonlinear = Vec::with_capacity(states.len());
    let mut nonlinear_failures = 0;
    for (k, x_bar) in states.iter().enumerate() {
        run::stop::check(stop)?;
        let started = Instant::now();
        lin.step(k as u64, *x_bar, 0.0);
        linear.push(started.elapsed().as_secs_f64() * 1e6);
        let started = Instant::now();
        let plan = nonlin.step(k as u64, *x_bar, 0.0);
        nonlinear.push(started.elapsed().as_secs_f64() * 1e6);
        nonlinear_failures += usize::from(!plan.is_solved());
    }
    Ok(SolveTimes {
        horizon,
        linear_us: Percentiles::of(&linear),
        nonlinear_us: Percentiles::of(&nonlinear),
        nonlinear_failures,
    })
}

/// The estimate `x_bar` at every sample boundary of the scenario's in-process run
/// (recorded in `dir`).
fn closed_loop_states(
    scenario: &Validated,
    dir: &Path,
    stop: &AtomicBool,
) -> anyhow::Result<Vec<[f64; 4]>> {
    let mut states = Vec::new();
    inprocess::run_observed(scenario, dir, Recording::files(false), stop, |tick| {
        if tick.plan.is_some() {
            states.push(tick.estimate.state);
        }
    })?;
    Ok(states)
}

/// `solve_times.csv`: a row per horizon, the percentiles of both formulations, µs.
pub fn write_csv(path: &Path, times: &[SolveTimes]) -> anyhow::Result<()> {
    let mut text = String::from(
        "horizon,linear_p50_us,linear_p99_us,linear_max_us,nonlinear_p50_us,nonlinear_p99_us,nonlinear_max_us,nonlinear_failures\n",
    );
    for s in times {
        text.push_str(&format!(
            "{},{:.1},{:.1},{:.1},{:.1},{:.1},{:.1},{}\n",
            s.horizon,
            s.linear_us.p50,
            s.linear_us.p99,
            s.linear_us.max,
            s.nonlinear_us.p50,
            s.nonlinear_us.p99,
            s.nonlinear_us.max,
            s.nonlinear_failures
        ));
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
