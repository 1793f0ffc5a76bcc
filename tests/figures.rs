//! The figures: the paper's set from `scmpc figures`, and the plots of one run. (A test
//! binary of its own: the solve-time comparison inside `scmpc figures` runs alone, not
//! beside the sweeps of `tests/study.rs`.)

use crate::common;

use common::{csv, num, scmpc, stderr};
use record::schema::Table;
use std::path::Path;

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

/// Also: without `--out` the figures go into a fresh directory under `runs/` of the
/// working directory (never over the checkout's `docs/figures`), and `scmpc figures` says
/// where.
#[test]
fn the_figure_set_has_every_figure_with_its_series_and_the_linear_schemes_slow_solves_are_faster() {
    let _machine = common::machine_shared();
    let cwd = tempfile::tempdir().unwrap();
    let out = scmpc()
        .arg("figures")
        .current_dir(cwd.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", stderr(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let said = (stdout.lines())
        .find_map(|l| l.strip_prefix("figures directory: "))
        .unwrap_or_else(|| panic!("no `figures directory:` line in {stdout}"));
    assert!(said.starts_with("runs/figures-"), "{said}");
    assert!(!cwd.path().join("docs").exists());
    let dir = cwd.path().join(said);
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
        let svg = std::fs::read_to_string(dir.as_path().join(format!("{stem}.svg"))).unwrap();
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
        let (w, h, colours, ink) = png_content(&dir.as_path().join(format!("{stem}.png")));
        assert!(w >= 600 && h >= 400, "{stem}.png is {w}x{h}");
        assert!(colours > 8, "{stem}.png has {colours} colours");
        assert!(
            ink > 0.02 && ink < 0.9,
            "{stem}.png: {:.1} % ink",
            ink * 100.0
        );
    }
    // The samples that set the time budget, the slow ones, are faster with the linear
    // scheme at every N. (The medians are about equal: from the shifted plan the
    // nonlinear SQP mostly converges in one subproblem, as the linear scheme needs one
    // solve; docs/study.md.)
    let times = csv(&dir.as_path().join("solve_times.csv"));
    assert_eq!(times.len(), 5);
    for row in &times {
        let (linear, nonlinear) = (num(row, "linear_p99_us"), num(row, "nonlinear_p99_us"));
        assert!(
            linear < nonlinear,
            "N = {}: linear p99 {linear} µs, nonlinear {nonlinear} µs",
            row["horizon"]
        );
    }
}

/// `scmpc run` in process for 6 s into a fresh directory, with no system font to be
/// found (an empty font directory and home) and `SCMPC_FONT` as given.
fn run_without_system_fonts(font: Option<&str>) -> (tempfile::TempDir, std::process::Output) {
    let dir = tempfile::tempdir().unwrap();
    let empty = tempfile::tempdir().unwrap();
    let mut command = scmpc();
    command
        .args(["run", "--in-process", "--set", "duration_s=6", "--out"])
        .arg(dir.path())
        .env_remove("SCMPC_FONT")
        .env("HOME", empty.path())
        .env("XDG_DATA_HOME", empty.path())
        .env("XDG_DATA_DIRS", empty.path())
        .env("FONTCONFIG_PATH", empty.path());
    if let Some(font) = font {
        command.env("SCMPC_FONT", font);
    }
    (dir, command.output().unwrap())
}

#[test]
fn a_run_writes_its_path_and_distance_plots_with_no_system_font() {
    let _machine = common::machine_shared();
    // SCMPC_FONT unset, and set but empty (a script's way to unset it): the embedded font.
    let (_, empty) = run_without_system_fonts(Some(""));
    assert_eq!(empty.status.code(), Some(1), "{}", stderr(&empty));
    assert!(!stderr(&empty).contains("no plots"), "{}", stderr(&empty));
    let (dir, out) = run_without_system_fonts(None);
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out)); // 6 s: not reached
    assert!(!stderr(&out).contains("no plots"), "{}", stderr(&out));
    let path = std::fs::read_to_string(dir.path().join("path.svg")).unwrap();
    assert!(path.contains("<polygon") && path.contains("<polyline"));
    for label in ["start", "goal", "MPC prediction, every 1 s"] {
        assert!(path.contains(label), "path.svg lacks `{label}`");
    }
    // One prediction a second, N + 1 = 9 positions each, the first at t = 0.
    let predictions = Table::read(&dir.path().join("predictions.csv")).unwrap();
    let samples = predictions.numbers("sample").unwrap();
    assert_eq!(samples.len(), 6 * 9);
    let mut firsts = samples.clone();
    firsts.dedup();
    assert_eq!(firsts, [0.0, 20.0, 40.0, 60.0, 80.0, 100.0]);
    let clearance = std::fs::read_to_string(dir.path().join("clearance.svg")).unwrap();
    assert!(clearance.contains("clearance (m)") && clearance.contains("<polyline"));
    for stem in ["path", "clearance"] {
        let (_, _, colours, ink) = png_content(&dir.path().join(format!("{stem}.png")));
        assert!(colours > 8 && ink > 0.02, "{stem}.png");
    }
}

#[test]
fn a_font_file_that_cannot_be_read_is_named_and_the_run_keeps_its_records() {
    let _machine = common::machine_shared();
    let (dir, out) = run_without_system_fonts(Some("/nonexistent/font.ttf"));
    let err = stderr(&out);
    assert!(
        err.contains("no plots") && err.contains("SCMPC_FONT=/nonexistent/font.ttf"),
        "{err}"
    );
    assert!(dir.path().join("trajectory.csv").exists());
    assert!(!dir.path().join("path.png").exists());
}

#[test]
fn ctrl_c_stops_scmpc_figures_during_its_solve_time_comparison_and_names_the_signal() {
    let _machine = common::machine_shared();
    let dir = tempfile::tempdir().unwrap();
    let mut child = scmpc()
        .args(["figures", "--out", dir.path().to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The comparison of the first horizon has begun once its closed loop has run (its
    // trajectory recorded): from there it solves every state in both formulations.
    let first = dir.path().join("runs/solve-time-n-8/summary.json");
    assert!(
        common::wait_for(std::time::Duration::from_secs(300), || first.exists()),
        "the solve-time comparison never began"
    );
    let signalled = std::time::Instant::now();
    // SAFETY: plain kill(2) of our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let exited = common::wait_for(std::time::Duration::from_secs(5), || {
        child.try_wait().unwrap().is_some()
    });
    let took = signalled.elapsed();
    if !exited {
        let _ = child.kill();
    }
    let out = child.wait_with_output().unwrap();
    assert!(exited, "still running 5 s after SIGINT");
    // What it takes from the signal to the exit is measured (docs/performance.md), not
    // asserted here beyond that it is not the rest of the comparison (seconds).
    assert!(took < std::time::Duration::from_secs(2), "took {took:?}");
    assert_ne!(out.status.code(), Some(0));
    assert!(
        stderr(&out).contains("interrupted by SIGINT"),
        "{}",
        stderr(&out)
    );
    assert!(!dir.path().join("solve_times.csv").exists());
}

/// The run in process of `args` into a fresh directory: its `path.svg` and
/// `clearance.svg`.
fn run_plots(args: &[&str]) -> (String, String) {
    let dir = tempfile::tempdir().unwrap();
    let out = scmpc()
        .args(["run", "--in-process", "-q", "--out"])
        .arg(dir.path())
        .args(args)
        .output()
        .unwrap();
    let read = |name: &str| {
        std::fs::read_to_string(dir.path().join(name))
            .unwrap_or_else(|e| panic!("{args:?}: {name}: {e}: {}", stderr(&out)))
    };
    (read("path.svg"), read("clearance.svg"))
}

/// How often `text` is a whole text element of an SVG (plotters writes each on a line of
/// its own, `'` as `&apos;`).
fn texts(svg: &str, text: &str) -> usize {
    let text = text.replace('\'', "&apos;");
    svg.lines().filter(|l| l.trim() == text).count()
}

/// The plots of a run say what they show (checked by their text, not their pixels): the
/// clearance named for a point robot or from a footprint's edge, to the obstacle or the
/// nearest of several, with the contact and margin lines and the contacts marked; the
/// path with the obstacles grown by footprint and margin and, with a person crossing,
/// each time written once beside the robot and once beside the person, one legend entry
/// per kind of thing.
#[test]
fn the_plots_of_a_run_name_what_they_show() {
    let _machine = common::machine_shared();
    let (path, clearance) = run_plots(&["--set", "duration_s=6"]);
    assert_eq!(texts(&clearance, "paper: clearance to the obstacle"), 1);
    assert_eq!(
        texts(&clearance, "robot (a point) to the obstacle's surface"),
        1
    );
    assert_eq!(texts(&clearance, "contact (0 m)"), 1);
    assert!(!clearance.contains("margin the MPC keeps") && !clearance.contains("in contact"));
    assert!(!path.contains("grown by") && texts(&path, "goal") == 1 && texts(&path, "start") == 1);

    let (path, clearance) = run_plots(&[
        "field",
        "--set",
        "duration_s=6",
        "--set",
        "robot.radius_m=0.3",
        "--set",
        "mpc.safety_margin_m=0.1",
    ]);
    let edge = "robot's edge (footprint 0.30 m) to the nearest obstacle's surface";
    assert_eq!(texts(&clearance, edge), 1);
    assert_eq!(
        texts(
            &clearance,
            "field: clearance to the nearest of 13 obstacles"
        ),
        1
    );
    assert_eq!(texts(&clearance, "margin the MPC keeps (0.10 m)"), 1);
    assert_eq!(texts(&path, "grown by footprint and margin (0.40 m)"), 1);

    let (path, _) = run_plots(&["crossing"]);
    assert_eq!(texts(&path, "robot (footprint) at the times written"), 1);
    assert_eq!(texts(&path, "moving obstacle at the same times"), 1);
    for time in ["0 s", "4 s", "8 s"] {
        assert_eq!(
            texts(&path, time),
            2,
            "`{time}` beside the robot and the person"
        );
    }

    // A faulty MPC without the safety check drives into the obstacle: marked.
    let (_, clearance) = run_plots(&[
        "--set",
        "duration_s=10",
        "--set",
        "fault.mpc_ignore_obstacles=true",
        "--set",
        "dfl.gatekeeper=false",
    ]);
    assert!(
        clearance
            .lines()
            .any(|l| l.trim().starts_with("in contact (")),
        "no contact marked"
    );
}
