//! The paper's study: sweeps, Monte Carlo under noise, the nonlinear baseline, figures.

use crate::common;

use common::{csv, num, run, run_into_tempdir, stderr};
use std::path::Path;

#[test]
fn the_sweep_reproduces_the_papers_qualitative_findings() {
    let _machine = common::machine_shared();
    let (dir, out) = run_into_tempdir(&[
        "sweep",
        "--grid",
        "mpc.gamma=0.1,0.3,0.5,0.7,0.9,1",
        "--grid",
        "mpc.horizon=8,14",
        "--grid",
        "mpc.constraint=cbf,euclidean",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let rows = csv(&dir.path().join("sweep.csv"));
    assert_eq!(rows.len(), 24);
    let find = |gamma: &str, horizon: &str, constraint: &str| {
        rows.iter()
            .find(|r| {
                r["mpc.gamma"] == gamma
                    && r["mpc.horizon"] == horizon
                    && r["mpc.constraint"] == constraint
            })
            .unwrap()
    };
    let gammas = ["0.1", "0.3", "0.5", "0.7", "0.9", "1"];
    for horizon in ["8", "14"] {
        // A smaller gamma starts deviating from the straight path earlier.
        let swerve: Vec<f64> = gammas
            .iter()
            .map(|g| num(find(g, horizon, "cbf"), "deviation_time_s"))
            .collect();
        assert!(
            swerve.windows(2).all(|w| w[0] <= w[1]) && swerve[0] < swerve[5],
            "N = {horizon}: deviation times by gamma {swerve:?}"
        );
        // The CBF starts deviating earlier than the Euclidean constraint.
        let euclidean = num(find("0.1", horizon, "euclidean"), "deviation_time_s");
        assert!(
            swerve[0] < euclidean,
            "N = {horizon}: CBF {} vs Euclidean {euclidean}",
            swerve[0]
        );
        // No run with gamma < 1 collides in the nominal case.
        for g in &gammas[..5] {
            let row = find(g, horizon, "cbf");
            assert_eq!(row["outcome"], "reached", "gamma {g}, N = {horizon}");
            assert!(num(row, "min_clearance_m") > 0.0);
        }
    }
    // Every run keeps its directory.
    assert!(Path::new(&rows[0]["dir"]).join("trajectory.csv").exists());
}

#[test]
fn with_the_ekf_a_hundred_noise_seeds_all_reach_the_goal_and_never_collide_but_kappa_0_does() {
    let _machine = common::machine_shared();
    let (dir, out) = run_into_tempdir(&[
        "sweep",
        "paper-noisy",
        "--grid",
        "mpc.uncertainty_sigmas=3,0",
        "--seeds",
        "100",
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let stats = csv(&dir.path().join("monte_carlo.csv"));
    let by_kappa = |kappa: &str| {
        stats
            .iter()
            .find(|r| r["mpc.uncertainty_sigmas"] == kappa)
            .unwrap()
    };
    // The paper's margin, kappa = 3 standard deviations of the estimate.
    let margin = by_kappa("3");
    assert_eq!(num(margin, "runs"), 100.0);
    assert_eq!(num(margin, "reached"), 100.0, "{margin:?}");
    assert_eq!(num(margin, "collisions"), 0.0, "{margin:?}");
    assert!(num(margin, "clearance_min_m") > 0.0);
    // Without it the same seeds graze the obstacle: the margin is what keeps them out.
    let none = by_kappa("0");
    assert_eq!(num(none, "runs"), 100.0);
    assert!(num(none, "collisions") > 0.0, "{none:?}");
    assert_eq!(csv(&dir.path().join("sweep.csv")).len(), 200);
}

#[test]
fn a_bad_grid_is_refused_before_anything_runs() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("sweep");
    for grid in ["mpc.gama=0.1,0.2", "mpc.gamma=0.1,7", "mpc.gamma"] {
        let out = run(&["sweep", "--grid", grid, "--out", out_dir.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2), "{grid}: {}", stderr(&out));
        assert!(stderr(&out).contains("mpc.ga"), "{grid}: {}", stderr(&out));
        assert!(!out_dir.exists());
    }
}
