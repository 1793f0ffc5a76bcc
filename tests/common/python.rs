//! A venv of the tests' own under the target directory, with pinned packages from PyPI
//! ([`PYTHON_PACKAGES`]): it needs CPython 3.11 or newer with pip (`python3`, or the
//! interpreter named by `SCMPC_TEST_PYTHON`) and the network to PyPI.

use super::stderr;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

/// What the venv holds: iceoryx2's Python bindings, the version of the Rust side, the
/// MCAP reader the recording is checked with, a JSON Schema validator for its schemas, the
/// ROS 2 CDR and type hashes the crate
/// `ros2` is checked with, and Zenoh for the simulated ROS 2 base (the version of the
/// Rust side).
const PYTHON_PACKAGES: [&str; 5] = [
    "iceoryx2==0.10.0",
    "mcap==1.6.0",
    "jsonschema==4.23.0",
    "rosbags==0.11.9",
    "eclipse-zenoh==1.10.2",
];

pub fn repo() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The venv's interpreter, made (once per test binary, kept between runs) if it is missing
/// or holds other packages.
pub fn python() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(|| {
        let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("python-venv");
        let python = venv.join("bin").join("python");
        let marker = venv.join("scmpc-packages.txt");
        let wanted = PYTHON_PACKAGES.join("\n");
        if std::fs::read_to_string(&marker).is_ok_and(|m| m == wanted) && python.exists() {
            return python;
        }
        let base = std::env::var("SCMPC_TEST_PYTHON").unwrap_or_else(|_| "python3".into());
        let _ = std::fs::remove_dir_all(&venv);
        let made = Command::new(&base).args(["-m", "venv"]).arg(&venv).output();
        let made = made.unwrap_or_else(|e| panic!("cannot run `{base}` (CPython 3.11+): {e}"));
        assert!(made.status.success(), "{base} -m venv: {}", stderr(&made));
        let pip = Command::new(&python)
            .args([
                "-m",
                "pip",
                "install",
                "--quiet",
                "--disable-pip-version-check",
            ])
            .args(PYTHON_PACKAGES)
            .output()
            .unwrap();
        assert!(pip.status.success(), "pip install: {}", stderr(&pip));
        std::fs::write(&marker, wanted).unwrap();
        python
    })
}

/// Runs the venv's Python on `script` with `args` (and `stdin`); fails the test on a
/// non-zero exit. Returns its standard output.
pub fn run_python(script: &Path, args: &[&Path], stdin: &[u8]) -> String {
    use std::io::Write;
    let mut child = Command::new(python())
        .arg(script)
        .args(args)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(stdin).unwrap();
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{}: {stdout}{}",
        script.display(),
        stderr(&out)
    );
    stdout
}

/// Every topic of `run.mcap` as `tests/python/read_mcap.py` read it: with its summary,
/// or with `scan` record by record in file order (a file cut short).
pub fn read_mcap(dir: &Path, scan: bool) -> serde_json::Value {
    let script = repo().join("tests/python/read_mcap.py");
    let file = dir.join("run.mcap");
    let mut args = vec![file.as_path()];
    if scan {
        args.push(Path::new("--scan"));
    }
    let out = run_python(&script, &args, b"");
    serde_json::from_str(&out).unwrap()
}
