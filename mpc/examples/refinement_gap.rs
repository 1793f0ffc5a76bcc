//! How far the default refinement tolerance leaves each plan from a fully refined one:
//! `cargo run --release -p mpc --example refinement_gap [KEY=VALUE ...]` (scenario
//! overrides as for `scmpc run --set`, e.g. `mpc.gamma=0.3 mpc.horizon=14`).
//!
//! Two MPCs see the same states, those of the scenario's closed loop under the first
//! (the robot following each plan's first predicted state exactly): one with the
//! scenario's `mpc.refinement_tol_m`, one refining to 10 µm. Prints the largest distance
//! between their predicted positions, how many samples the tolerance stopped after one
//! solve where the full refinement went on, and how far the first MPC's plans moved from
//! the previous plan shifted by one sample (stages 1 to N - 1, the samples after the
//! first), which is what the tolerance is compared with.

use mpc::Mpc;
use protocol::Scenario;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let overrides: Vec<String> = std::env::args().skip(1).collect();
    let scenario = Scenario::default().with_overrides(&overrides)?;
    let mut refined_scenario = scenario.clone();
    refined_scenario.mpc.refinement_tol_m = 1e-5;
    refined_scenario.mpc.max_solves = 20;
    let (mut mpc, mut refined) = (Mpc::new(&scenario)?, Mpc::new(&refined_scenario)?);

    let [x, y, theta] = scenario.robot.start;
    let mut x_bar = [x, y, theta, scenario.robot.zeta0];
    let (mut largest_gap_m, mut gap_sample, mut stopped_early) = (0.0_f64, 0, 0);
    let mut largest_move_m = 0.0_f64;
    let mut previous: Option<protocol::Plan> = None;
    let samples = (scenario.duration_s / scenario.timing.ts_s).round() as u64;
    for k in 0..samples {
        let (plan, full) = (mpc.step(k, x_bar, 0.0), refined.step(k, x_bar, 0.0));
        if !plan.is_solved() || !full.is_solved() {
            return Err(format!("sample {k}: not solved").into());
        }
        let n = plan.horizon as usize;
        let distance = |a: [f64; 4], b: [f64; 4]| (a[0] - b[0]).hypot(a[2] - b[2]);
        let gap = (1..=n)
            .map(|i| distance(plan.z[i], full.z[i]))
            .fold(0.0, f64::max);
        if let Some(previous) = previous {
            largest_move_m = (1..n)
                .map(|i| distance(plan.z[i], previous.z[i + 1]))
                .fold(largest_move_m, f64::max);
        }
        previous = Some(plan);
        if gap > largest_gap_m {
            (largest_gap_m, gap_sample) = (gap, k);
        }
        stopped_early += u32::from(plan.solves == 1 && full.solves > 1);
        let z = plan.z[1];
        x_bar = protocol::phi_inverse(z, x_bar[2]);
    }
    println!(
        "refinement_tol_m {}: largest gap to the refined plan {:.3} mm (sample {gap_sample}); \
         {stopped_early} of {samples} samples stopped after one solve where refining went on; \
         plans moved up to {:.1} mm from the shifted previous plan",
        scenario.mpc.refinement_tol_m,
        largest_gap_m * 1e3,
        largest_move_m * 1e3
    );
    Ok(())
}
