//! The `scmpc` executable; everything lives in the `orchestrator` crate.

fn main() -> std::process::ExitCode {
    orchestrator::cli::main()
}
