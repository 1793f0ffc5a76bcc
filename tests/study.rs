//! The paper's study: sweeps, Monte Carlo under noise, the nonlinear baseline, figures.

mod common;

use common::{run, stderr};
use std::collections::HashMap;
use std::path::Path;

/// A CSV file as rows of `column -> value`.
fn csv(path: &Path) -> Vec<HashMap<String, String>> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines
        .map(|l| {
            header
                .iter()
                .cloned()
                .zip(l.split(',').map(String::from))
                .collect()
        })
        .collect()
}

fn num(row: &HashMap<String, String>, column: &str) -> f64 {
    row[column]
        .parse()
        .unwrap_or_else(|_| panic!("{column} = {:?}", row[column]))
}

#[test]
fn the_sweep_reproduces_the_papers_qualitative_findings() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "sweep",
        "--grid",
        "mpc.gamma=0.1,0.3,0.5,0.7,0.9,1",
        "--grid",
        "mpc.horizon=8,14",
        "--grid",
        "mpc.constraint=cbf,euclidean",
        "--out",
        dir.path().to_str().unwrap(),
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
fn with_the_ekf_a_hundred_noise_seeds_never_collide() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "sweep",
        "paper-noisy",
        "--grid",
        "estimator.kind=ekf,passthrough",
        "--seeds",
        "100",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let stats = csv(&dir.path().join("monte_carlo.csv"));
    let by_kind = |kind: &str| stats.iter().find(|r| r["estimator.kind"] == kind).unwrap();
    let ekf = by_kind("ekf");
    assert_eq!(num(ekf, "runs"), 100.0);
    assert_eq!(num(ekf, "collisions"), 0.0, "{ekf:?}");
    assert!(num(ekf, "clearance_min_m") > 0.0);
    let passthrough = by_kind("passthrough");
    assert_eq!(num(passthrough, "runs"), 100.0);
    eprintln!(
        "collision rate over 100 seeds: EKF {}, passthrough {}",
        ekf["collision_rate"], passthrough["collision_rate"]
    );
    assert_eq!(csv(&dir.path().join("sweep.csv")).len(), 200);
}

/// Pixels of a PNG figure: `(width, height, distinct colours, share of non-white pixels)`.
fn png_content(path: &Path) -> (u32, u32, usize, f64) {
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    let pixels: Vec<&[u8]> = buf[..info.buffer_size()].chunks(3).collect();
    let colours: std::collections::HashSet<&[u8]> = pixels.iter().copied().collect();
    let ink = pixels.iter().filter(|p| **p != [255, 255, 255]).count();
    (
        info.width,
        info.height,
        colours.len(),
        ink as f64 / pixels.len() as f64,
    )
}

#[test]
fn the_figure_set_has_every_figure_with_its_series_and_the_linear_scheme_solves_faster() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&["figures", "--out", dir.path().to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let expected: [(&str, &[&str]); 8] = [
        (
            "paths_gamma",
            &["γ = 0.1, N = 8", "γ = 0.5, N = 8", "γ = 1, N = 8"],
        ),
        (
            "paths_gamma_horizon",
            &["γ = 0.1, N = 9", "γ = 0.9, N = 14"],
        ),
        (
            "paths_cbf_euclidean",
            &["CBF, γ = 0.1", "Euclidean distance"],
        ),
        (
            "paths_noise",
            &["nominal", "noisy, EKF", "noisy, passthrough"],
        ),
        ("velocity", &["γ = 0.3, N = 8", "ζ (m/s)"]),
        (
            "distance",
            &["γ = 0.7, N = 8", "Euclidean, N = 8", "clearance (m)"],
        ),
        ("convergence", &["x, nominal", "ẏ, noisy (EKF)"]),
        (
            "solve_time",
            &[
                "linear (DFL), median",
                "nonlinear (SCNMPC), median",
                "Ts = 50 ms",
            ],
        ),
    ];
    for (stem, labels) in expected {
        let svg = std::fs::read_to_string(dir.path().join(format!("{stem}.svg"))).unwrap();
        for label in labels {
            assert!(svg.contains(label), "{stem}.svg lacks `{label}`");
        }
        // One polyline per series at least, each with many points.
        let lines = svg.matches("<polyline").count();
        assert!(
            lines >= labels.len().min(2),
            "{stem}.svg: {lines} polylines"
        );
        if stem.starts_with("paths") {
            assert!(svg.contains("<polygon"), "{stem}.svg: no obstacle");
            assert!(
                svg.contains("x (m)") && svg.contains("y (m)"),
                "{stem}.svg: axis units"
            );
        }
        let (w, h, colours, ink) = png_content(&dir.path().join(format!("{stem}.png")));
        assert!(w >= 600 && h >= 400, "{stem}.png is {w}x{h}");
        assert!(colours > 8, "{stem}.png has {colours} colours");
        assert!(
            ink > 0.02 && ink < 0.9,
            "{stem}.png: {:.1} % ink",
            ink * 100.0
        );
    }
    let times = csv(&dir.path().join("solve_times.csv"));
    assert_eq!(times.len(), 5);
    for row in &times {
        let (linear, nonlinear) = (num(row, "linear_p50_us"), num(row, "nonlinear_p50_us"));
        assert!(
            linear < nonlinear,
            "N = {}: linear median {linear} µs, nonlinear {nonlinear} µs",
            row["horizon"]
        );
    }
}

#[test]
fn a_run_writes_its_path_and_distance_plots() {
    let dir = tempfile::tempdir().unwrap();
    let out = run(&[
        "run",
        "--in-process",
        "--set",
        "duration_s=6",
        "--out",
        dir.path().to_str().unwrap(),
    ]);
    assert!(out.status.code().is_some(), "{}", stderr(&out));
    let path = std::fs::read_to_string(dir.path().join("path.svg")).unwrap();
    assert!(path.contains("<polygon") && path.contains("<polyline"));
    let clearance = std::fs::read_to_string(dir.path().join("clearance.svg")).unwrap();
    assert!(clearance.contains("clearance (m)") && clearance.contains("<polyline"));
    for stem in ["path", "clearance"] {
        let (_, _, colours, ink) = png_content(&dir.path().join(format!("{stem}.png")));
        assert!(colours > 8 && ink > 0.02, "{stem}.png");
    }
}

#[test]
fn a_bad_grid_is_refused_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("sweep");
    for grid in ["mpc.gama=0.1,0.2", "mpc.gamma=0.1,7", "mpc.gamma"] {
        let out = run(&["sweep", "--grid", grid, "--out", out_dir.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(2), "{grid}: {}", stderr(&out));
        assert!(stderr(&out).contains("mpc.ga"), "{grid}: {}", stderr(&out));
        assert!(!out_dir.exists());
    }
}
