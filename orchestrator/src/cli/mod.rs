//! The `scmpc` command line: [`args`] its grammar, [`launch`] the commands that run roles,
//! and here the dispatch and the study commands, each a call into the crate that does it.

use anyhow::Context;
use protocol::Role;
use run::scenarios;
use std::path::PathBuf;
use std::process::ExitCode;

/// Exit code of a run that did not reach the goal (collided, stalled, timed out,
/// interrupted) or failed at run time.
pub const EXIT_NOT_REACHED: u8 = 1;
/// Exit code of bad input: a scenario or an override that is refused before anything runs.
pub const EXIT_BAD_INPUT: u8 = 2;

mod args;
mod launch;

use args::{Cli, Command, FuzzArgs, IdentifyArgs, RoleArgs, SwapArgs, SweepArgs};
use clap::{CommandFactory, FromArgMatches};

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
    iceoryx2::prelude::set_log_level(iceoryx2::prelude::LogLevel::Error);
    let matches = args::with_roles(Cli::command()).get_matches();
    let sub = matches.subcommand();
    let verbosity = Verbosity {
        verbose: sub.map_or(0, |(_, sub)| sub.get_count("verbose")),
        quiet: sub.is_some_and(|(_, sub)| sub.get_flag("quiet")),
    };
    init_logging(verbosity);
    let role = sub.and_then(|(name, sub)| Some((Role::from_name(name)?, sub)));
    let result = match role {
        Some((role, sub)) => {
            let args = RoleArgs::from_arg_matches(sub).unwrap_or_else(|e| e.exit());
            launch::role(args, role)
        }
        None => dispatch(
            Cli::from_arg_matches(&matches)
                .unwrap_or_else(|e| e.exit())
                .command,
            verbosity,
        ),
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

/// `-v` (counted) and `-q`.
#[derive(Debug, Clone, Copy, Default)]
struct Verbosity {
    verbose: u8,
    quiet: bool,
}

/// Runs `command` (every command but a role process's).
fn dispatch(command: Command, verbosity: Verbosity) -> CliResult {
    match command {
        Command::Schema => {
            println!("{:#}", message_schema());
            Ok(())
        }
        Command::Scenario { name } => scenario(&name),
        Command::Run(args) => launch::run(args, verbosity.quiet),
        Command::Swap(args) => swap(args),
        Command::Sweep(args) => sweep(args, !verbosity.quiet),
        Command::Fuzz(args) => fuzz(args, !verbosity.quiet),
        Command::Identify(args) => identify(args),
        Command::Figures { out } => figures(out),
        Command::Ps => {
            ps();
            Ok(())
        }
        Command::Topics { run_dir, seconds } => topics(&run_dir, seconds),
        Command::Echo {
            topic,
            run_dir,
            count,
        } => {
            let stop = run::stop::on_signals();
            let mut out = std::io::stdout().lock();
            run::watch::echo(&run_dir, &topic, count, &stop, &mut out).map_err(bad_input)?;
            Ok(())
        }
        Command::Keys { filter } => keys(filter.as_deref()),
        Command::Bench {
            out,
            realtime_s,
            swap8_s,
            load,
            runs,
        } => bench(out, (realtime_s, swap8_s), load, runs, !verbosity.quiet),
        Command::BenchBurn => study::bench::load::burn(),
        Command::BenchPong { prefix, zenoh } => bench_pong(prefix, zenoh),
        Command::Host(args) => launch::host(args),
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

/// Refuses a ROS 2 robot for `command`, which runs the simulated plant in process.
fn simulated(scenario: &protocol::Validated, command: &str) -> CliResult {
    match scenario.plant.kind {
        protocol::PlantKind::Sim => Ok(()),
        protocol::PlantKind::Ros2 => Err(bad_input(format!(
            "plant.kind = \"ros2\": scmpc {command} runs the simulated plant in process; \
             a robot is driven by `scmpc run --mode realtime`"
        ))),
    }
}

/// `scmpc sweep`; `progress`: a progress bar (or lines).
fn sweep(args: SweepArgs, progress: bool) -> CliResult {
    use study::sweep;
    let base = scenarios::load(args.scenario.as_deref(), &args.overrides).map_err(bad_input)?;
    simulated(&base, "sweep")?;
    let axes = (args.grid.iter())
        .map(|g| sweep::Axis::parse(g))
        .collect::<Result<Vec<_>, _>>()
        .map_err(bad_input)?;
    let out = (args.out.clone())
        .unwrap_or_else(|| record::run_dir::default_run_dir(&format!("{}-sweep", base.name)));
    let runs = sweep::plan_runs(&base, &axes, args.seeds, &out).map_err(bad_input)?;
    let stop = run::stop::on_signals();
    let threads = args.threads.unwrap_or_else(cores);
    eprintln!(
        "{} runs on {threads} threads into {}",
        runs.len(),
        out.display()
    );
    let results = sweep::run_all(&runs, threads, progress, args.mcap, &stop);
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
    run::stop::check(&stop).map_err(|e| CliError::Failed(e.into()))?;
    if results.iter().all(Result::is_ok) {
        Ok(())
    } else {
        Err(CliError::NotReached)
    }
}

/// `--people`: a share of the worlds, 0 to 1, `default` when not given.
fn people_share(people: Option<f64>, default: f64) -> Result<f64, CliError> {
    let share = people.unwrap_or(default);
    match (0.0..=1.0).contains(&share) {
        true => Ok(share),
        false => Err(bad_input(format!(
            "--people {share}: must be a share of the worlds, 0 to 1"
        ))),
    }
}

/// `scmpc fuzz`; `progress`: a progress bar (or lines).
fn fuzz(args: FuzzArgs, progress: bool) -> CliResult {
    if let Some(robots) = &args.robots {
        return fleet_fuzz(&args, robots);
    }
    // Every world is drawn and validated before anything runs.
    let people = people_share(args.people, study::fuzz::PEOPLE)?;
    let draws = study::fuzz::Draws {
        people,
        lidar: args.perception == args::FuzzPerception::Lidar,
    };
    let first = study::fuzz::world(args.seed, 0, draws, &args.overrides).map_err(bad_input)?;
    simulated(&first.scenario, "fuzz")?;
    let (out, threads) = fuzz_batch(&args, "fuzz", "worlds");
    let stop = run::stop::on_signals();
    let batch = study::fuzz::Batch {
        seed: args.seed,
        count: args.count,
        draws,
    };
    let report =
        study::fuzz::run(batch, &args.overrides, &out, threads, progress, &stop).map_err(|e| {
            match e.downcast_ref::<protocol::ScenarioErrors>() {
                Some(bad) => bad_input(bad),
                None => CliError::Failed(e),
            }
        })?;
    print!("{}", report.table());
    println!("fuzz directory: {}", out.display());
    run::stop::check(&stop).map_err(|e| CliError::Failed(e.into()))?;
    if report.collisions() > 0 {
        Err(CliError::NotReached)
    } else {
        Ok(())
    }
}

/// `scmpc ps`: the runs going on on this machine.
fn ps() {
    let runs = run::watch::running();
    if runs.is_empty() {
        println!("no run is going on on this machine");
        return;
    }
    println!("{:>8}  {:9}  {:16}  directory", "pid", "clock", "scenario");
    for r in runs {
        println!(
            "{:>8}  {:9}  {:16}  {}",
            r.pid,
            r.mode,
            r.scenario,
            r.dir.display()
        );
    }
}

/// `scmpc topics`: the data topics of the run in `dir`, with their rates over `seconds`.
fn topics(dir: &std::path::Path, seconds: f64) -> CliResult {
    if !(seconds.is_finite() && seconds > 0.0) {
        return Err(bad_input(format!("--for must be positive, got {seconds}")));
    }
    let stop = run::stop::on_signals();
    let over = protocol::wait_of_s(seconds);
    let topics = run::watch::topic_rates(dir, over, &stop).map_err(bad_input)?;
    println!(
        "{:14}  {:>9}  {:10}  type",
        "topic", "rate (Hz)", "producer"
    );
    for t in topics {
        println!(
            "{:14}  {:>9.1}  {:10}  {}",
            t.topic, t.rate_hz, t.producer, t.message
        );
    }
    Ok(())
}

/// `scmpc keys`: every scenario key with `filter` in it, as a table.
fn keys(filter: Option<&str>) -> CliResult {
    let keys: Vec<_> = (protocol::scenario::keys::catalogue().into_iter())
        .filter(|k| filter.is_none_or(|f| k.key.contains(f)))
        .collect();
    if keys.is_empty() {
        return Err(bad_input(format!(
            "no scenario key contains `{}` (`scmpc keys` lists them all)",
            filter.unwrap_or_default()
        )));
    }
    let width = |column: fn(&protocol::scenario::keys::KeyDoc) -> &str| {
        keys.iter()
            .map(|k| column(k).chars().count())
            .max()
            .unwrap_or(0)
    };
    let (key_w, type_w, unit_w) = (width(|k| &k.key), width(|k| &k.kind), width(|k| k.unit));
    let default_w = width(|k| &k.default).min(24);
    println!(
        "{:key_w$}  {:type_w$}  {:unit_w$}  {:default_w$}  meaning",
        "key", "type", "unit", "default"
    );
    for k in &keys {
        println!(
            "{:key_w$}  {:type_w$}  {:unit_w$}  {:default_w$}  {}",
            k.key, k.kind, k.unit, k.default, k.meaning
        );
    }
    Ok(())
}

fn figures(out: Option<PathBuf>) -> CliResult {
    let out = out.unwrap_or_else(|| record::run_dir::default_run_dir("figures"));
    let stop = run::stop::on_signals();
    eprintln!("drawing the paper's figures into {}", out.display());
    let set = study::figures::paper_set(&out, cores(), &stop)?;
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
    println!("figures directory: {}", out.display());
    Ok(())
}

fn bench_pong(prefix: Option<String>, zenoh: Option<String>) -> CliResult {
    match (prefix, zenoh) {
        (_, Some(endpoint)) => {
            let endpoint = protocol::endpoint::Endpoint::parse(&endpoint).map_err(bad_input)?;
            study::bench::cross_host::zenoh_pong(&endpoint).map_err(CliError::Failed)
        }
        (Some(prefix), None) => study::bench::pong(&prefix).map_err(CliError::Failed),
        (None, None) => Err(bad_input("--prefix or --zenoh is required")),
    }
}

/// `scmpc identify`: the excitation checked for room, driven (the simulated plant, or the
/// ROS 2 robot of `plant.kind = "ros2"`), fitted and printed.
fn identify(args: IdentifyArgs) -> CliResult {
    use study::identify::{Excitation, check_room, identify_ros2, identify_simulated};
    let scenario = scenarios::load(args.scenario.as_deref(), &args.overrides).map_err(bad_input)?;
    for (option, value) in [
        ("--speed", args.speed),
        ("--turn", args.turn),
        ("--within", args.within),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(bad_input(format!("{option} must be positive, got {value}")));
        }
    }
    let excitation = Excitation {
        speed_m_s: args.speed,
        turn_rad_s: args.turn,
    };
    let identified = match scenario.plant.kind {
        protocol::PlantKind::Sim => {
            let dt_s = scenario.timing.dt_s();
            let (reach_m, duration_s) = (excitation.reach_m(dt_s), excitation.duration_s(dt_s));
            check_room(&scenario, reach_m, args.within, duration_s).map_err(bad_input)?;
            identify_simulated(&scenario, excitation).map_err(anyhow::Error::from)?
        }
        protocol::PlantKind::Ros2 => {
            let stop = run::stop::on_signals();
            identify_ros2(&scenario, excitation, args.within, &stop).map_err(|e| {
                match e.downcast_ref::<study::identify::RoomError>() {
                    Some(_) => bad_input(format!("{e:#}")),
                    None => e.into(),
                }
            })?
        }
    };
    print!("{}", identified.as_toml());
    Ok(())
}

/// `scmpc bench`; `progress`: a line as each phase begins.
fn bench(
    out: Option<PathBuf>,
    (realtime_s, swap8_s): (f64, Option<f64>),
    load: Option<usize>,
    runs: usize,
    progress: bool,
) -> CliResult {
    if !(realtime_s.is_finite() && realtime_s > 0.0) {
        return Err(bad_input(format!(
            "--realtime-s must be positive, got {realtime_s}"
        )));
    }
    if swap8_s.is_some_and(|s| !(s.is_finite() && s > 0.0)) {
        return Err(bad_input("--swap8-s must be positive"));
    }
    if load == Some(0) || runs == 0 {
        return Err(bad_input("--load and --runs must be at least 1"));
    }
    let out = out.unwrap_or_else(|| record::run_dir::default_run_dir("bench"));
    let stop = run::stop::on_signals();
    if let Some(load) = load {
        run::scheduling::check(&protocol::RealtimeConfig::default()).map_err(bad_input)?;
        let report = study::bench::load::measure(&out, load, runs, realtime_s, &stop)?;
        print!("{}", report.table());
        println!("bench directory: {}", out.display());
        return Ok(());
    }
    let report = study::bench::run(&out, (realtime_s, swap8_s), progress, &stop)?;
    print!("{}", report.table());
    println!("bench directory: {}", out.display());
    Ok(())
}

fn swap(args: SwapArgs) -> CliResult {
    let request = run::swap_client::swappable_role(&args.role)
        .and_then(|role| run::swap_client::build_request(role, &args.command))
        .map_err(bad_input)?;
    let stop = run::stop::on_signals();
    let reply = run::swap_client::send(&args.run_dir, &request, &stop).map_err(|e| {
        if e.downcast_ref::<run::swap_client::RequestError>().is_some() {
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

/// What `scmpc schema` prints.
fn message_schema() -> serde_json::Value {
    use run::children::{
        ENV_CONTROL_PUBLISHER, ENV_EPOCH, ENV_MODE, ENV_PREFIX, ENV_ROBOT, ENV_ROLE, ENV_SCENARIO,
        ENV_SUPERVISOR,
    };
    use runtime::layout;
    serde_json::json!({
        "iceoryx2": "0.10.0",
        "service_type": "ipc",
        "root_path": runtime::ipc::ROOT_PATH,
        "user_header": "()",
        "services": layout::services(),
        "types": layout::types(),
        "codes": layout::codes(),
        "events": record::EventLine::schema(),
        "graph": graph_schema(),
        "environment": {
            ENV_SCENARIO: "the run's scenario file (TOML, every key written out)",
            ENV_PREFIX: "the iceoryx2 prefix of the run's resources (config.global.prefix)",
            ENV_MODE: "lockstep or realtime",
            ENV_EPOCH: "the producer epoch to stamp on every sample (Header.epoch)",
            ENV_ROLE: "the role to play",
            ENV_ROBOT: "the robot whose pipeline the process is part of: its services are robot<id>/<topic>, and Header.robot of every sample (0 when unset)",
            ENV_SUPERVISOR: "the supervisor's pid (the orchestrator, or on another host its agent): brake and exit when it is gone",
            ENV_CONTROL_PUBLISHER: "the iceoryx2 id of the orchestrator's control publisher, hexadecimal",
            runtime::ipc::ENV_RUN_ID: "the run id every Header.run carries, decimal (set on other hosts, whose prefix differs from the orchestrator's; else derived from the prefix)",
            runtime::clock::ENV_CLOCK_CORRECTION_NS: "ns to add to this host's monotonic clock to read the orchestrator's (set on other hosts, docs/hosts.md)",
            runtime::clock::ENV_CLOCK_OFFSET_MS: "a test's artificial offset of this process's clock, ms (docs/hosts.md)",
        },
    })
}

/// The declared graph as `scmpc schema` prints it: each data topic (type, rate, producer)
/// and each role (inputs, outputs, tier, whether it may run on another host).
fn graph_schema() -> serde_json::Value {
    use protocol::graph::{ROBOT, ROLES, TOPICS, producer_of};
    let topics: serde_json::Map<String, serde_json::Value> = TOPICS
        .iter()
        .map(|t| {
            let producer = producer_of(t.name).map(protocol::Role::as_str);
            let about = serde_json::json!({ "type": t.message, "rate": t.rate.as_str(), "producer": producer });
            (t.name.to_string(), about)
        })
        .collect();
    let role = |d: &protocol::graph::RoleDecl| {
        serde_json::json!({
            "inputs": d.inputs, "outputs": d.outputs,
            "tier": format!("{:?}", d.tier).to_lowercase(), "remote": d.remote,
            "optional": d.optional,
        })
    };
    let mut roles: serde_json::Map<String, serde_json::Value> = ROLES
        .iter()
        .map(|d| (d.role.as_str().to_string(), role(d)))
        .collect();
    roles.insert("plant (ros2)".into(), role(&ROBOT));
    serde_json::json!({ "topics": topics, "roles": roles })
}

/// The log's filter: `-v`/`-q` if given, else `SCMPC_LOG`, else `RUST_LOG`, else warnings
/// (the libraries' own chatter off).
fn init_logging(verbosity: Verbosity) {
    use tracing_subscriber::EnvFilter;
    let flags = match (verbosity.quiet, verbosity.verbose) {
        (true, _) => Some("error,zenoh=error,foxglove=off"),
        (false, 0) => None,
        (false, 1) => Some("info,zenoh=warn,foxglove=warn"),
        (false, _) => Some("debug"),
    };
    let filter = match flags {
        Some(flags) => EnvFilter::new(flags),
        None => (EnvFilter::try_from_env("SCMPC_LOG"))
            .or_else(|_| EnvFilter::try_from_env("RUST_LOG"))
            .unwrap_or_else(|_| "warn,zenoh=error,foxglove=off".into()),
    };
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .try_init();
}

/// Where a fuzz batch of `what` goes (`--out`, else a fresh run directory named after
/// `name` and the seed) and on how many threads, said on stderr.
fn fuzz_batch(args: &FuzzArgs, name: &str, what: &str) -> (std::path::PathBuf, usize) {
    let out = (args.out.clone())
        .unwrap_or_else(|| record::run_dir::default_run_dir(&format!("{name}-{}", args.seed)));
    let threads = args.threads.unwrap_or_else(cores);
    eprintln!(
        "{} {what} (seed {}) on {threads} threads into {}",
        args.count,
        args.seed,
        out.display()
    );
    (out, threads)
}

/// `scmpc fuzz --robots A..B` (docs/fleet.md, "Fuzz"): exit 1 when a robot moved into
/// another or into an obstacle, or a world failed to run.
fn fleet_fuzz(args: &FuzzArgs, robots: &str) -> CliResult {
    let range = robot_range(robots).map_err(bad_input)?;
    let extras = study::fleet_fuzz::Extras {
        lidar: args.perception == args::FuzzPerception::Lidar,
        people: people_share(args.people, 0.0)?,
    };
    study::fleet_fuzz::world(args.seed, 0, &range, extras, &args.overrides).map_err(bad_input)?;
    let (out, threads) = fuzz_batch(args, "fleet-fuzz", &format!("fleets of {robots} robots"));
    let stop = run::stop::on_signals();
    let batch = (args.seed, args.count);
    let report =
        study::fleet_fuzz::run(batch, range, extras, &args.overrides, &out, threads, &stop)
            .map_err(CliError::Failed)?;
    print!("{}", report.table());
    println!("fuzz directory: {}", out.display());
    run::stop::check(&stop).map_err(|e| CliError::Failed(e.into()))?;
    match report.contacts_moving() > 0 || report.collided() > 0 || report.errors() > 0 {
        true => Err(CliError::Failed(anyhow::anyhow!(
            "a robot moved into another or into an obstacle, or a world did not run: see {}",
            out.join("fleet_fuzz.csv").display()
        ))),
        false => Ok(()),
    }
}

/// `A..B` or `N` robots, each from 1 to [`protocol::MAX_ROBOTS`].
fn robot_range(text: &str) -> Result<std::ops::RangeInclusive<usize>, String> {
    let parse = |t: &str| t.trim().parse::<usize>().ok();
    let (low, high) = match text.split_once("..") {
        Some((a, b)) => (parse(a), parse(b.trim_start_matches('='))),
        None => (parse(text), parse(text)),
    };
    match (low, high) {
        (Some(a), Some(b)) if 1 <= a && a <= b && b <= protocol::MAX_ROBOTS => Ok(a..=b),
        _ => Err(format!(
            "--robots {text}: not `A..B` or `N` with 1 <= A <= B <= {}",
            protocol::MAX_ROBOTS
        )),
    }
}
