//! How much slower an MPC step is after the process has been idle, as every step of a
//! real-time run is (the MPC waits `Ts` = 50 ms for the next estimate):
//! `cargo run --release -p mpc --example idle_gap`.
//!
//! Steps the MPC over the first 200 samples of the paper run, once back to back, once
//! after sleeping before every step, once after sleeping and then spinning (the core
//! awake, its caches as the sleep left them), and after sleeping and then warming up
//! (`Mpc::warm_up`: a dry step of the next sample from the state the last plan predicts,
//! what the real-time MPC process does shortly before each sample's estimate comes) with
//! 0, 0.5 or 3 ms between the warm-up and the step (the warm-up's effect fades within
//! milliseconds: docs/performance.md, "The warm-up, just in time"). Prints each case's
//! percentiles, and the warm-ups' own.

use mpc::Mpc;
use protocol::Scenario;
use std::time::{Duration, Instant};

const SAMPLES: usize = 200;

fn main() -> Result<(), mpc::MpcError> {
    let scenario = Scenario::default();
    let states = paper_states(&scenario)?;
    // (sleep before each step ms, then spin µs, then warm up and sleep µs before the step)
    for (sleep_ms, spin_us, warm_up) in [
        (0, 0, None),
        (50, 0, None),
        (50, 100, None),
        (50, 2000, None),
        (50, 0, Some(0)),
        (50, 0, Some(500)),
        (50, 0, Some(3000)),
    ] {
        let mut mpc = Mpc::new(&scenario)?;
        let never: protocol::task::Cancel = std::rc::Rc::new(|| false);
        let mut warm_up_us = Vec::new();
        let mut step_us: Vec<f64> = states
            .iter()
            .enumerate()
            .map(|(k, &x_bar)| {
                std::thread::sleep(Duration::from_millis(sleep_ms));
                let spin = Instant::now();
                while spin.elapsed() < Duration::from_micros(spin_us) {
                    std::hint::spin_loop();
                }
                if let Some(gap_us) = warm_up.filter(|_| k > 0) {
                    let started = Instant::now();
                    mpc.warm_up(u64::MAX, &never);
                    warm_up_us.push(started.elapsed().as_secs_f64() * 1e6);
                    std::thread::sleep(Duration::from_micros(gap_us));
                }
                let started = Instant::now();
                mpc.step(k as u64, x_bar, 0.0);
                started.elapsed().as_secs_f64() * 1e6
            })
            .collect();
        let (p50, p90) = percentiles(&mut step_us);
        let warm_up_label = match warm_up {
            Some(gap_us) => format!("warm up {gap_us:>4} µs before"),
            None => "no warm-up".into(),
        };
        print!(
            "sleep {sleep_ms:>2} ms, spin {spin_us:>4} µs, {warm_up_label:>24}: step p50 \
             {p50:>4.0} µs, p90 {p90:>4.0} µs"
        );
        if warm_up.is_some() {
            let (p50, p90) = percentiles(&mut warm_up_us);
            print!(" (warm-up p50 {p50:.0} µs, p90 {p90:.0} µs)");
        }
        println!();
    }
    Ok(())
}

/// p50 and p90 of `values`, µs.
fn percentiles(values: &mut [f64]) -> (f64, f64) {
    values.sort_by(f64::total_cmp);
    let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.9))
}

/// The estimates `x_bar` of the paper run's first samples, the robot following each
/// plan's first predicted state exactly.
fn paper_states(scenario: &Scenario) -> Result<Vec<[f64; 4]>, mpc::MpcError> {
    let mut mpc = Mpc::new(scenario)?;
    let [x, y, theta] = scenario.robot.start;
    let mut x_bar = [x, y, theta, scenario.robot.zeta0];
    let mut states = Vec::with_capacity(SAMPLES);
    for k in 0..SAMPLES {
        states.push(x_bar);
        let z = mpc.step(k as u64, x_bar, 0.0).z[1];
        x_bar = protocol::phi_inverse(z, x_bar[2]);
    }
    Ok(states)
}
