//! The `scmpc` command line.

use crate::{inprocess, multiproc, scenarios};
use anyhow::Context;
use clap::{Parser, Subcommand};
use protocol::Role;
use runtime::clock::RunMode;
use runtime::process::ProcessArgs;
use std::path::PathBuf;
use std::process::ExitCode;

/// Exit code of a run that did not reach the goal (collided, stalled, timed out,
/// interrupted) or failed at run time.
pub const EXIT_NOT_REACHED: u8 = 1;
/// Exit code of bad input: a scenario or an override that is refused before anything runs.
pub const EXIT_BAD_INPUT: u8 = 2;

#[derive(Debug, Parser)]
#[command(
    name = "scmpc",
    version,
    about = "Safety-critical linear MPC with CBFs and DFL for a differential-drive robot"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a scenario and write its records to a run directory.
    Run(RunArgs),
    /// Replace a role process of a running multi-process run, make-before-break.
    ///
    /// The replacement starts with the next epoch, warms up on live inputs, and takes over
    /// at a sample boundary; then the old process is stopped. Without COMMAND a fresh
    /// built-in process of the role is started. The command gets the run's scenario,
    /// prefix, mode and its epoch in SCMPC_* environment variables; a program named `scmpc`
    /// is the running scmpc executable. Exit 0: swapped; 1: the swap failed (the old
    /// process still runs); 2: bad input or no run going.
    Swap(SwapArgs),
    /// Run every combination of a parameter grid in process, on all cores.
    ///
    /// Writes `sweep.csv` (one row per run: the grid values and the summary's numbers) and
    /// keeps each run's directory under `runs/`; with `--seeds N`, every combination runs
    /// with noise seeds 1..=N and `monte_carlo.csv` gives the collision rate and the
    /// distribution of the minimum clearance per combination.
    Sweep(SweepArgs),
    /// Run random valid worlds in process, on all cores, and report how they ended.
    ///
    /// Writes `fuzz.csv` (one row per world: its parameters, outcome, stall reason,
    /// minimum clearance, safety interventions, solver failures) and, for every world that
    /// did not reach the goal, its scenario under `failed/` (`scmpc run FILE` replays it).
    /// Exit 1 if any world collided, 2 on bad input.
    Fuzz(FuzzArgs),
    /// Draw the paper's figure set from scratch (SVG and PNG) into a directory.
    Figures {
        /// Directory of the figures [default: docs/figures].
        #[arg(long, value_name = "DIR", default_value = "docs/figures")]
        out: PathBuf,
    },
    /// Benchmark the pipeline end to end against a raw iceoryx2 ping-pong; prints a table
    /// and writes bench.json.
    Bench {
        /// Directory of the runs and bench.json [default: a fresh directory under runs/].
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Length of the real-time run, s.
        #[arg(long, default_value_t = 10.0)]
        realtime_s: f64,
    },
    /// The other end of `scmpc bench`'s ping-pong (started by it).
    #[command(hide = true)]
    BenchPong {
        /// The iceoryx2 ping-pong's prefix.
        #[arg(long, required_unless_present = "zenoh")]
        prefix: Option<String>,
        /// The Zenoh ping-pong's endpoint, instead.
        #[arg(long, conflicts_with = "prefix")]
        zenoh: Option<String>,
    },
    /// Print, as JSON, the layout of every message crossing a process boundary and what a
    /// role process of another language needs to join a run.
    ///
    /// Each topic's iceoryx2 service and settings, each type's iceoryx2 name, size,
    /// alignment and fields (name, offset, type), the codes of every enumeration, and the
    /// environment a role process is started with (docs/python.md).
    Schema,
    /// Print a built-in scenario (paper, paper-noisy, field) as TOML, to copy and edit.
    Scenario {
        /// Name of the built-in scenario.
        #[arg(default_value = "paper")]
        name: String,
    },
    /// The agent of a host: runs the roles a scenario places on this host, run after run
    /// (docs/hosts.md).
    ///
    /// Listens on a Zenoh endpoint; an orchestrator given `--host NAME=ENDPOINT` joins it
    /// to its run. Stops on Ctrl-C, stopping the processes of a run it serves.
    Host(HostArgs),
    /// Role process: the plant (started by `scmpc run`).
    Plant(RoleArgs),
    /// Role process: the state estimator (started by `scmpc run`).
    Estimator(RoleArgs),
    /// Role process: the MPC (started by `scmpc run`).
    Mpc(RoleArgs),
    /// Role process: the DFL inner loop (started by `scmpc run`).
    Dfl(RoleArgs),
    /// Role process: the route planner (started by `scmpc run` when `planner.kind =
    /// "route"`).
    Planner(RoleArgs),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum Mode {
    /// Simulated time, deterministic, as fast as the machine allows.
    Lockstep,
    /// Paced by the monotonic wall clock.
    Realtime,
}

impl From<Mode> for RunMode {
    fn from(m: Mode) -> RunMode {
        match m {
            Mode::Lockstep => RunMode::Lockstep,
            Mode::Realtime => RunMode::Realtime,
        }
    }
}

/// What the orchestrator passes to a role process: on the command line, or in the
/// environment of any command it starts for a role (docs/design.md, "Supervision"), so a
/// replacement such as `scmpc mpc --set mpc.horizon=10` needs only its own options.
#[derive(Debug, clap::Args)]
struct RoleArgs {
    /// The run's scenario file (the orchestrator writes it into the run directory).
    #[arg(long, env = crate::children::ENV_SCENARIO)]
    scenario: String,
    /// The run's iceoryx2 resource prefix.
    #[arg(long, env = crate::children::ENV_PREFIX)]
    prefix: String,
    #[arg(long, value_enum, default_value = "lockstep", env = crate::children::ENV_MODE)]
    mode: Mode,
    /// The producer epoch stamped on every sample.
    #[arg(long, default_value_t = 0, env = crate::children::ENV_EPOCH)]
    epoch: u32,
    /// The orchestrator's pid: when it is gone, the robot is stopped and the process exits.
    #[arg(long, env = crate::children::ENV_SUPERVISOR)]
    supervisor_pid: Option<u32>,
    /// The iceoryx2 id of the orchestrator's control publisher (hexadecimal): control
    /// messages from any other publisher are refused.
    #[arg(long, env = crate::children::ENV_CONTROL_PUBLISHER, value_parser = parse_hex_id)]
    control_publisher: Option<u128>,
    /// Override a value of the run's scenario for this process only, e.g.
    /// `mpc.horizon=10` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
}

#[derive(Debug, clap::Args)]
struct SweepArgs {
    /// Scenario file, or the name of a built-in scenario [default: paper].
    scenario: Option<String>,
    /// An axis of the grid: a dotted key and its values, e.g. `mpc.gamma=0.1,0.3,0.5`
    /// (repeatable; every combination runs).
    #[arg(long = "grid", value_name = "KEY=V1,V2,...")]
    grid: Vec<String>,
    /// Override a scenario value for every run (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Noise seeds per combination (seeds 1..=N); 0 keeps the scenario's seed.
    #[arg(long, default_value_t = 0)]
    seeds: u64,
    /// Sweep directory [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Runs at a time [default: the number of cores].
    #[arg(long)]
    threads: Option<usize>,
    /// Write each run's `run.mcap` too (docs/foxglove.md).
    #[arg(long)]
    mcap: bool,
}

#[derive(Debug, clap::Args)]
struct FuzzArgs {
    /// Number of worlds.
    #[arg(long, default_value_t = 200)]
    count: usize,
    /// Seed of the batch (the same seed draws the same worlds).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Override a value in every world, e.g. `plant.noise_variance=0.01` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Directory of fuzz.csv and the failed worlds [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// Runs at a time [default: the number of cores].
    #[arg(long)]
    threads: Option<usize>,
}

#[derive(Debug, clap::Args)]
struct SwapArgs {
    /// Directory of the running run (its `run.json`).
    #[arg(long = "run", value_name = "DIR")]
    run_dir: PathBuf,
    /// Role to replace: estimator, mpc or dfl.
    role: String,
    /// Program and arguments of the replacement, after `--`, e.g.
    /// `-- scmpc mpc --set mpc.horizon=10`.
    #[arg(last = true, value_name = "COMMAND")]
    command: Vec<String>,
}

/// How this side secures its links to other hosts (docs/hosts.md).
#[derive(Debug, clap::Args)]
struct SecurityArgs {
    /// The CA certificate (PEM) both sides trust: TLS with mutual authentication.
    #[arg(long, value_name = "FILE", requires_all = ["tls_cert", "tls_key"])]
    tls_ca: Option<PathBuf>,
    /// This side's certificate (PEM), signed by the CA.
    #[arg(long, value_name = "FILE", requires_all = ["tls_ca", "tls_key"])]
    tls_cert: Option<PathBuf>,
    /// This side's private key (PEM).
    #[arg(long, value_name = "FILE", requires_all = ["tls_ca", "tls_cert"])]
    tls_key: Option<PathBuf>,
    /// Allow plain TCP to or from an address that is not on loopback.
    #[arg(long)]
    insecure: bool,
}

impl SecurityArgs {
    fn security(&self) -> Result<hosts::net::Security, CliError> {
        let tls = match (&self.tls_ca, &self.tls_cert, &self.tls_key) {
            (Some(ca), Some(certificate), Some(private_key)) => Some(hosts::net::TlsFiles {
                ca: ca.clone(),
                certificate: certificate.clone(),
                private_key: private_key.clone(),
            }),
            _ => None,
        };
        let security = hosts::net::Security {
            tls,
            insecure: self.insecure,
        };
        security.check_files().map_err(bad_input)?;
        Ok(security)
    }
}

#[derive(Debug, clap::Args)]
struct HostArgs {
    /// The host's name, as scenarios place roles on it (`[hosts] mpc = "NAME"`).
    #[arg(long)]
    name: String,
    /// Where to listen: `tcp/ADDR:PORT` (loopback, or with --insecure) or `tls/ADDR:PORT`.
    #[arg(long, value_name = "ENDPOINT")]
    listen: String,
    #[command(flatten)]
    security: SecurityArgs,
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// Scenario file, or the name of a built-in scenario [default: paper].
    scenario: Option<String>,
    /// Step every role's task in this process (deterministic; the reference for the other modes).
    #[arg(long)]
    in_process: bool,
    /// Override a scenario value by its dotted key, e.g. `mpc.gamma=0.3` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    overrides: Vec<String>,
    /// Run directory [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// iceoryx2 resource prefix of the run, to attach tools to it [default: a fresh one].
    #[arg(long, value_name = "PREFIX")]
    prefix: Option<String>,
    /// Clock of a multi-process run (`--in-process` is always lockstep).
    #[arg(long, value_enum, default_value = "lockstep")]
    mode: Mode,
    /// Do not write `run.mcap` (docs/foxglove.md).
    #[arg(long)]
    no_mcap: bool,
    /// Real time: keep every core busy at idle priority for the run, so that no core
    /// halts between samples (faster wake-ups and steps on a virtual machine, at the cost
    /// of all idle CPU; docs/performance.md, "Idle cores").
    #[arg(long)]
    keep_cores_awake: bool,
    /// Where the agent of a host the scenario places roles on listens, e.g.
    /// `compute=tcp/127.0.0.1:7447` (repeatable; overrides `[hosts.endpoints]`).
    #[arg(long = "host", value_name = "NAME=ENDPOINT")]
    hosts: Vec<String>,
    #[command(flatten)]
    security: SecurityArgs,
}

/// Why a command did not succeed. [`main`] prints it and maps it to the exit code, the
/// one place that does.
#[derive(Debug)]
enum CliError {
    /// Bad input, named (the file, key, flag or value): nothing ran. Exit
    /// [`EXIT_BAD_INPUT`].
    BadInput(String),
    /// The command ran and printed its report, but missed its goal (a run that did not
    /// reach the goal, a fuzz world that collided, a sweep run that failed). Exit
    /// [`EXIT_NOT_REACHED`].
    NotReached,
    /// The command could not run to its end. Exit [`EXIT_NOT_REACHED`].
    Failed(anyhow::Error),
}

impl From<anyhow::Error> for CliError {
    fn from(e: anyhow::Error) -> Self {
        CliError::Failed(e)
    }
}

fn bad_input(e: impl std::fmt::Display) -> CliError {
    CliError::BadInput(e.to_string())
}

type CliResult = Result<(), CliError>;

/// Parses the command line and runs it.
pub fn main() -> ExitCode {
    init_logging();
    iceoryx2::prelude::set_log_level(iceoryx2::prelude::LogLevel::Error);
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Schema => {
            println!("{:#}", message_schema());
            Ok(())
        }
        Command::Scenario { name } => scenario(&name),
        Command::Run(args) => run(args),
        Command::Swap(args) => swap(args),
        Command::Sweep(args) => sweep(args),
        Command::Fuzz(args) => fuzz(args),
        Command::Figures { out } => figures(&out),
        Command::Bench { out, realtime_s } => bench(out, realtime_s),
        Command::BenchPong { prefix, zenoh } => bench_pong(prefix, zenoh),
        Command::Host(args) => host(args),
        Command::Plant(args) => role(args, Role::Plant),
        Command::Estimator(args) => role(args, Role::Estimator),
        Command::Mpc(args) => role(args, Role::Mpc),
        Command::Dfl(args) => role(args, Role::Dfl),
        Command::Planner(args) => role(args, Role::Planner),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::BadInput(message)) => {
            // Scenario errors end in a newline of their own (one line per key).
            eprint!("error: {message}");
            if !message.ends_with('\n') {
                eprintln!();
            }
            ExitCode::from(EXIT_BAD_INPUT)
        }
        Err(CliError::NotReached) => ExitCode::from(EXIT_NOT_REACHED),
        Err(CliError::Failed(e)) => {
            eprintln!("error: {e:#}");
            ExitCode::from(EXIT_NOT_REACHED)
        }
    }
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

fn scenario(name: &str) -> CliResult {
    let text = scenarios::built_in(name).ok_or_else(|| {
        let names: Vec<&str> = scenarios::BUILT_IN.iter().map(|(n, _)| *n).collect();
        bad_input(format!(
            "no built-in scenario `{name}` (there are: {})",
            names.join(", ")
        ))
    })?;
    print!("{text}");
    Ok(())
}

fn sweep(args: SweepArgs) -> CliResult {
    use crate::sweep;
    let base = scenarios::load(args.scenario.as_deref(), &args.overrides).map_err(bad_input)?;
    let axes = (args.grid.iter())
        .map(|g| sweep::Axis::parse(g))
        .collect::<Result<Vec<_>, _>>()
        .map_err(bad_input)?;
    let out =
        (args.out.clone()).unwrap_or_else(|| default_run_dir(&format!("{}-sweep", base.name)));
    let runs = sweep::plan_runs(&base, &axes, args.seeds, &out).map_err(bad_input)?;
    let stop = crate::stop::on_signals();
    let threads = args.threads.unwrap_or_else(cores);
    eprintln!(
        "{} runs on {threads} threads into {}",
        runs.len(),
        out.display()
    );
    let results = sweep::run_all(&runs, threads, true, args.mcap, &stop);
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    sweep::write_sweep_csv(&out.join("sweep.csv"), &axes, &runs, &results)?;
    let stats = sweep::seed_stats(&runs, &results);
    if args.seeds > 0 {
        sweep::write_seed_stats(&out.join("monte_carlo.csv"), &axes, &stats)?;
    }
    if args.seeds > 1 {
        print!("{}", sweep::seed_table(&axes, &stats));
    } else {
        print!("{}", sweep::run_table(&axes, &runs, &results));
    }
    println!("sweep directory: {}", out.display());
    crate::stop::check(&stop).map_err(|e| CliError::Failed(e.into()))?;
    if results.iter().all(Result::is_ok) {
        Ok(())
    } else {
        Err(CliError::NotReached)
    }
}

fn fuzz(args: FuzzArgs) -> CliResult {
    // Every world is drawn and validated before anything runs.
    crate::fuzz::world(args.seed, 0, &args.overrides).map_err(bad_input)?;
    let out = args
        .out
        .unwrap_or_else(|| default_run_dir(&format!("fuzz-{}", args.seed)));
    let threads = args.threads.unwrap_or_else(cores);
    eprintln!(
        "{} worlds (seed {}) on {threads} threads into {}",
        args.count,
        args.seed,
        out.display()
    );
    let stop = crate::stop::on_signals();
    let report = crate::fuzz::run(
        args.seed,
        args.count,
        &args.overrides,
        &out,
        threads,
        true,
        &stop,
    )
    .map_err(|e| match e.downcast_ref::<protocol::ScenarioErrors>() {
        Some(bad) => bad_input(bad),
        None => CliError::Failed(e),
    })?;
    print!("{}", report.table());
    println!("fuzz directory: {}", out.display());
    crate::stop::check(&stop).map_err(|e| CliError::Failed(e.into()))?;
    if report.collisions() > 0 {
        Err(CliError::NotReached)
    } else {
        Ok(())
    }
}

fn figures(out: &std::path::Path) -> CliResult {
    let stop = crate::stop::on_signals();
    let set = crate::figures::paper_set(out, cores(), &stop)?;
    println!("horizon  linear p50 / p99 (µs)   nonlinear p50 / p99 (µs)");
    for s in &set.solve_times {
        println!(
            "{:>7}  {:>8.0} / {:<8.0}     {:>8.0} / {:<8.0}",
            s.horizon, s.linear_us.p50, s.linear_us.p99, s.nonlinear_us.p50, s.nonlinear_us.p99
        );
    }
    for f in &set.files {
        println!("{}", f.display());
    }
    Ok(())
}

fn bench_pong(prefix: Option<String>, zenoh: Option<String>) -> CliResult {
    match (prefix, zenoh) {
        (_, Some(endpoint)) => {
            let endpoint = protocol::endpoint::Endpoint::parse(&endpoint).map_err(bad_input)?;
            crate::bench::cross_host::zenoh_pong(&endpoint).map_err(CliError::Failed)
        }
        (Some(prefix), None) => crate::bench::pong(&prefix).map_err(CliError::Failed),
        (None, None) => Err(bad_input("--prefix or --zenoh is required")),
    }
}

fn bench(out: Option<PathBuf>, realtime_s: f64) -> CliResult {
    if !(realtime_s.is_finite() && realtime_s > 0.0) {
        return Err(bad_input(format!(
            "--realtime-s must be positive, got {realtime_s}"
        )));
    }
    let out = out.unwrap_or_else(|| default_run_dir("bench"));
    let stop = crate::stop::on_signals();
    let report = crate::bench::run(&out, realtime_s, &stop)?;
    print!("{}", report.table());
    println!("bench directory: {}", out.display());
    Ok(())
}

fn swap(args: SwapArgs) -> CliResult {
    let request = crate::swap_client::swappable_role(&args.role)
        .and_then(|role| crate::swap_client::build_request(role, &args.command))
        .map_err(bad_input)?;
    let stop = crate::stop::on_signals();
    let reply = crate::swap_client::send(&args.run_dir, &request, &stop).map_err(|e| {
        if e.downcast_ref::<crate::swap_client::RequestError>()
            .is_some()
        {
            bad_input(format!("{e:#}"))
        } else {
            CliError::Failed(e)
        }
    })?;
    if reply.done != 1 {
        return Err(CliError::Failed(anyhow::anyhow!(
            "swap of the {} failed: {}",
            args.role,
            reply.message()
        )));
    }
    println!(
        "swapped {}: epoch {} from tick {} ({})",
        args.role,
        reply.epoch,
        reply.switch_tick,
        reply.message()
    );
    Ok(())
}

/// Runs one role process until the orchestrator stops it.
fn role(args: RoleArgs, this: Role) -> CliResult {
    // A replacement command that starts the wrong role would only be refused, sample by
    // sample, as the wrong epoch: say so at once.
    if let Ok(wanted) = std::env::var(crate::children::ENV_ROLE)
        && wanted != this.as_str()
    {
        return Err(bad_input(format!(
            "this is the {} process, but the run started it as its {wanted} ({})",
            this.as_str(),
            crate::children::ENV_ROLE
        )));
    }
    runtime::clock::clock_shift_from_env().map_err(bad_input)?;
    let scenario = scenarios::load(Some(&args.scenario), &args.overrides).map_err(bad_input)?;
    // A process of its own may change what it computes, never the loop's clock.
    if !args.overrides.is_empty()
        && scenarios::load(Some(&args.scenario), &[]).is_ok_and(|run| run.timing != scenario.timing)
    {
        return Err(bad_input("--set: `timing.*` must match the run's scenario"));
    }
    let process_args = ProcessArgs {
        scenario,
        prefix: args.prefix.clone(),
        mode: args.mode.into(),
        epoch: args.epoch,
        supervisor_pid: args.supervisor_pid,
        control_publisher: args.control_publisher,
    };
    let result = crate::roles::serve(this, &process_args);
    // Orphaned (the orchestrator or the host's agent is dead): the last process of the run
    // to exit removes the run's resources, as nobody else will until the next run or agent
    // starts on this machine.
    if args
        .supervisor_pid
        .is_some_and(|pid| !runtime::ipc::process_alive(pid))
    {
        let _ = runtime::ipc::remove_run(&args.prefix);
    }
    result.map_err(|e| CliError::Failed(anyhow::Error::msg(e.to_string())))
}

/// An iceoryx2 port id as printed by iceoryx2 (hexadecimal).
fn parse_hex_id(text: &str) -> Result<u128, String> {
    u128::from_str_radix(text, 16).map_err(|e| format!("`{text}` is not a hexadecimal id: {e}"))
}

fn run(args: RunArgs) -> CliResult {
    let scenario = scenarios::load(args.scenario.as_deref(), &args.overrides).map_err(bad_input)?;
    scenarios::check_swap_programs(&scenario).map_err(bad_input)?;
    let out = args.out.unwrap_or_else(|| default_run_dir(&scenario.name));
    if args.in_process && args.mode == Mode::Realtime {
        return Err(bad_input(
            "--in-process runs in lockstep only; drop --mode realtime or --in-process",
        ));
    }
    if args.keep_cores_awake && args.mode != Mode::Realtime {
        return Err(bad_input(
            "--keep-cores-awake is for --mode realtime (lockstep keeps its cores busy already)",
        ));
    }
    let prefix = args.prefix.unwrap_or_else(runtime::ipc::new_prefix);
    runtime::ipc::run_config(&prefix).map_err(|e| bad_input(format!("--prefix: {e}")))?;
    let hosts = if args.in_process {
        multiproc::HostsSetup::default()
    } else {
        hosts_setup(
            &scenario,
            &args.hosts,
            args.security.security()?,
            args.mode.into(),
        )?
    };
    let stop = crate::stop::on_signals();
    let awake = args
        .keep_cores_awake
        .then(crate::awake::AwakeCores::start)
        .transpose()
        .context("keeping the cores awake")?;
    let summary = if args.in_process {
        inprocess::run(&scenario, &out, !args.no_mcap, &stop)
    } else {
        multiproc::run(
            &scenario,
            &out,
            args.mode.into(),
            &prefix,
            &hosts,
            !args.no_mcap,
            &stop,
        )
    }
    .with_context(|| format!("run of `{}`", scenario.name))?;
    drop(awake);
    if let Err(e) = crate::figures::run_plots(&out, &scenario) {
        eprintln!("warning: no plots for the run: {e:#}");
    }
    println!("run directory: {}", out.display());
    print!("{}", summary.table());
    if summary.outcome == crate::judge::Outcome::Reached {
        Ok(())
    } else {
        Err(CliError::NotReached)
    }
}

/// Where each host the scenario places a role on listens (the scenario's
/// `[hosts.endpoints]`, then `--host NAME=ENDPOINT`), each endpoint allowed by `security`.
fn hosts_setup(
    scenario: &protocol::Validated,
    flags: &[String],
    security: hosts::net::Security,
    mode: RunMode,
) -> Result<multiproc::HostsSetup, CliError> {
    use protocol::endpoint::{Endpoint, is_host_name};
    let mut endpoints = std::collections::BTreeMap::new();
    for (name, text) in &scenario.hosts.endpoints {
        let endpoint =
            Endpoint::parse(text).map_err(|e| bad_input(format!("hosts.endpoints.{name}: {e}")))?;
        endpoints.insert(name.clone(), endpoint);
    }
    for flag in flags {
        let (name, text) = flag
            .split_once('=')
            .ok_or_else(|| bad_input(format!("--host {flag}: not NAME=ENDPOINT")))?;
        if !is_host_name(name) || name == hosts::keys::ORCHESTRATOR {
            return Err(bad_input(format!(
                "--host {flag}: `{name}` is no host name"
            )));
        }
        let endpoint =
            Endpoint::parse(text).map_err(|e| bad_input(format!("--host {flag}: {e}")))?;
        endpoints.insert(name.to_string(), endpoint);
    }
    let used = scenario.hosts.names();
    for name in &used {
        let endpoint = endpoints.get(name).ok_or_else(|| {
            bad_input(format!(
                "host `{name}`: no endpoint (give --host {name}=tcp/ADDR:PORT or [hosts.endpoints] {name})"
            ))
        })?;
        security
            .allows(endpoint)
            .map_err(|e| bad_input(format!("host `{name}`: {e}")))?;
    }
    let f = &scenario.fault;
    let link_faults = f.link_delay_ms > 0.0 || f.link_loss > 0.0 || f.link_is_ever_down();
    if link_faults && !used.is_empty() && mode == RunMode::Lockstep {
        return Err(bad_input(
            "fault.link_*: the link faults act in real time (give --mode realtime); \
             in lockstep a lost grant would stop the clock",
        ));
    }
    endpoints.retain(|name, _| used.contains(name));
    Ok(multiproc::HostsSetup {
        endpoints,
        security,
    })
}

/// `scmpc host`: the agent of this host, until Ctrl-C.
fn host(args: HostArgs) -> CliResult {
    use protocol::endpoint::{Endpoint, is_host_name};
    if !is_host_name(&args.name) || args.name == hosts::keys::ORCHESTRATOR {
        return Err(bad_input(format!(
            "--name {}: a host name is letters, digits, `-` and `_` (and not `{}`)",
            args.name,
            hosts::keys::ORCHESTRATOR
        )));
    }
    let listen = Endpoint::parse(&args.listen).map_err(|e| bad_input(format!("--listen: {e}")))?;
    let security = args.security.security()?;
    security
        .allows(&listen)
        .map_err(|e| bad_input(format!("--listen: {e}")))?;
    runtime::clock::clock_shift_from_env().map_err(bad_input)?;
    let stop = crate::stop::on_signals();
    crate::agent::serve(&args.name, &listen, &security, &stop)?;
    Ok(())
}

/// What `scmpc schema` prints.
fn message_schema() -> serde_json::Value {
    use crate::children::{
        ENV_CONTROL_PUBLISHER, ENV_EPOCH, ENV_MODE, ENV_PREFIX, ENV_ROLE, ENV_SCENARIO,
        ENV_SUPERVISOR,
    };
    use runtime::layout;
    serde_json::json!({
        "iceoryx2": "0.10.0",
        "service_type": "ipc",
        "user_header": "()",
        "services": layout::services(),
        "types": layout::types(),
        "codes": layout::codes(),
        "environment": {
            ENV_SCENARIO: "the run's scenario file (TOML, every key written out)",
            ENV_PREFIX: "the iceoryx2 prefix of the run's resources (config.global.prefix)",
            ENV_MODE: "lockstep or realtime",
            ENV_EPOCH: "the producer epoch to stamp on every sample (Header.epoch)",
            ENV_ROLE: "the role to play",
            ENV_SUPERVISOR: "the supervisor's pid (the orchestrator, or on another host its agent): brake and exit when it is gone",
            ENV_CONTROL_PUBLISHER: "the iceoryx2 id of the orchestrator's control publisher, hexadecimal",
            runtime::ipc::ENV_RUN_ID: "the run id every Header.run carries, decimal (set on other hosts, whose prefix differs from the orchestrator's; else derived from the prefix)",
            runtime::clock::ENV_CLOCK_CORRECTION_NS: "ns to add to this host's monotonic clock to read the orchestrator's (set on other hosts, docs/hosts.md)",
            runtime::clock::ENV_CLOCK_OFFSET_MS: "a test's artificial offset of this process's clock, ms (docs/hosts.md)",
        },
    })
}

/// `runs/<name>-<UTC yyyymmdd-hhmmss>`, made unique with a counter if it exists.
fn default_run_dir(name: &str) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let base = format!("{name}-{}", utc_stamp(secs));
    let mut dir = PathBuf::from("runs").join(&base);
    let mut n = 1;
    while dir.exists() {
        n += 1;
        dir = PathBuf::from("runs").join(format!("{base}-{n}"));
    }
    dir
}

/// `yyyymmdd-hhmmss` of a Unix time, UTC (civil-from-days, proleptic Gregorian).
fn utc_stamp(unix_s: u64) -> String {
    let days = (unix_s / 86_400) as i64;
    let rem = unix_s % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}{month:02}{day:02}-{:02}{:02}{:02}",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_env("SCMPC_LOG")
        .unwrap_or_else(|_| "warn,zenoh=error".into());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamp_formats_known_instants() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        assert_eq!(utc_stamp(951_782_400), "20000229-000000");
        assert_eq!(utc_stamp(1_795_299_065), "20261121-221105");
    }
}
