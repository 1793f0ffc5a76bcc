//! Helpers shared by the cross-process tests: run the real `scmpc` executable.

#![allow(dead_code)]

use std::path::Path;
use std::process::{Command, Output};

pub fn scmpc() -> Command {
    Command::new(env!("CARGO_BIN_EXE_scmpc"))
}

/// Runs `scmpc` with `args`, failing the test if it cannot be started.
pub fn run(args: &[&str]) -> Output {
    scmpc().args(args).output().expect("cannot start scmpc")
}

pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The run directory's `summary.json`.
pub fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).expect("summary.json missing");
    serde_json::from_str(&text).expect("summary.json is not JSON")
}
