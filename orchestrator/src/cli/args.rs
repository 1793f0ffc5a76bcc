//! The command line's grammar: every command and its arguments (clap).

use super::{CliError, bad_input};
use clap::{Parser, Subcommand};
use runtime::clock::RunMode;
use std::path::PathBuf;

#[derive(Debug, Parser)]
#[command(
    name = "scmpc",
    version,
    about = "Safety-critical linear MPC with CBFs and DFL for a differential-drive robot"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
    /// More log output: `-v` informs, `-vv` debugs (the same as `RUST_LOG=info`,
    /// `RUST_LOG=debug`; `RUST_LOG` takes any `tracing` filter).
    #[arg(short, long, global = true, action = clap::ArgAction::Count, conflicts_with = "quiet")]
    pub verbose: u8,
    /// Less output: errors only, and no status or progress lines (the end table stays).
    #[arg(short, long, global = true)]
    pub quiet: bool,
}

/// The help of a command's scenario argument: `lead`, then the built-in scenarios' names.
fn scenario_help(lead: &str) -> String {
    let names: Vec<&str> = run::scenarios::BUILT_IN.iter().map(|(n, _)| *n).collect();
    format!("{lead}: {}", names.join(", "))
}

/// Runs and sweeps: a file or a built-in scenario, the paper's by default.
fn file_or_built_in_help() -> String {
    scenario_help("Scenario file, or the name of a built-in scenario") + " [default: paper]"
}

#[derive(Debug, Subcommand)]
pub enum Command {
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
    /// did not reach the goal or touched an obstacle (at rest), its scenario under `failed/`
    /// (`scmpc run FILE` replays it).
    /// Exit 1 if any world collided, 2 on bad input.
    Fuzz(FuzzArgs),
    /// Measure the base's lag and command delay: drive a short excitation (steps and a
    /// chirp in forward speed and turn rate) from the robot's start, fit both per
    /// channel to the poses measured, and print them as scenario keys to paste
    /// (docs/robot.md).
    ///
    /// Drives the simulated plant (its `plant.actuator_lag_s`, `plant.command_delay_s`,
    /// noise and wheels) from `robot.start`, or the ROS 2 robot of `plant.kind = "ros2"`
    /// from where its odometry puts it, in real time (about 15 s). Refuses to start where
    /// the excitation would leave the position box or come near a known obstacle. Exit 2
    /// on bad input.
    Identify(IdentifyArgs),
    /// Draw the paper's figure set from scratch (SVG and PNG) into a directory.
    Figures {
        /// Directory of the figures [default: a fresh directory under runs/].
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Benchmark the pipeline end to end against a raw iceoryx2 ping-pong; prints a table
    /// and writes bench.json.
    Bench {
        /// Directory of the runs and bench.json [default: a fresh directory under runs/].
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Length of each real-time run, s.
        #[arg(long, default_value_t = 10.0)]
        realtime_s: f64,
        /// Length of the `swap8` runs, s [default: until every robot's goal].
        #[arg(long, value_name = "S")]
        swap8_s: Option<f64>,
        /// Instead: the real-time paper run beside N CPU-bound processes, with the
        /// real-time policy and without, against the idle machine (docs/performance.md,
        /// "Under load").
        #[arg(long, value_name = "N")]
        load: Option<usize>,
        /// With --load: runs of each condition.
        #[arg(long, default_value_t = 3, requires = "load")]
        runs: usize,
    },
    /// A CPU-bound process of `scmpc bench --load` (started by it).
    #[command(hide = true)]
    BenchBurn,
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
    /// Print a built-in scenario as TOML, to copy and edit (`scmpc keys` lists every key).
    Scenario {
        /// Name of the built-in scenario.
        #[arg(default_value = "paper", help = scenario_help("A built-in scenario"))]
        name: String,
    },
    /// List the multi-process runs going on on this machine: pid, clock, scenario, run
    /// directory.
    Ps,
    /// List the data topics of a running run with their rates (as `ros2 topic list`).
    ///
    /// Watches the run for a second (`--for`) without disturbing it: it only subscribes.
    Topics {
        /// Directory of the running run (`scmpc ps` lists them).
        #[arg(long = "run", value_name = "DIR")]
        run_dir: PathBuf,
        /// How long to count samples, s.
        #[arg(long = "for", value_name = "SECONDS", default_value_t = 1.0)]
        seconds: f64,
    },
    /// Print the samples of a topic of a running run as JSON lines (as `ros2 topic echo`).
    ///
    /// Read-only: it subscribes and never publishes, and its queue drops its oldest samples
    /// rather than hold up the run. Ends with the run, after `--count` samples, or on
    /// Ctrl-C. The fields are those of `scmpc schema`.
    Echo {
        /// The topic, e.g. `estimate` (`scmpc topics` lists them).
        topic: String,
        /// Directory of the running run (`scmpc ps` lists them).
        #[arg(long = "run", value_name = "DIR")]
        run_dir: PathBuf,
        /// Stop after this many samples.
        #[arg(long, value_name = "N")]
        count: Option<u64>,
    },
    /// List every scenario key: its type, unit, default and meaning.
    ///
    /// Read from the schema the scenario files and `--set` are parsed with, so the list is
    /// the whole set (a finished run's `scenario.toml` holds the same keys). `<i>` is an
    /// index of a list of tables (`obstacles.0.radius`), `<name>` a name of your choice.
    Keys {
        /// Only the keys that contain this text, e.g. `ros2` or `timeout`.
        filter: Option<String>,
    },
    /// The agent of a host: runs the roles a scenario places on this host, run after run
    /// (docs/hosts.md).
    ///
    /// Listens on a Zenoh endpoint; an orchestrator given `--host NAME=ENDPOINT` joins it
    /// to its run. Stops on Ctrl-C, stopping the processes of a run it serves.
    Host(HostArgs),
    // A role process (`scmpc plant`, `scmpc mpc`, ...): a subcommand per role of
    // `run::roles`, added by `with_roles`.
}

/// The command line with a subcommand per role, each taking [`RoleArgs`]: the roles come
/// from their registry ([`run::roles`]), so a new role needs no line here.
pub fn with_roles(cli: clap::Command) -> clap::Command {
    use clap::Args;
    cli.subcommands(run::roles::ALL.iter().map(|role| {
        let about = format!(
            "Role process: the {} (started by `scmpc run`)",
            role.as_str()
        );
        RoleArgs::augment_args(clap::Command::new(role.as_str())).about(about)
    }))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
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
pub struct RoleArgs {
    /// The run's scenario file (the orchestrator writes it into the run directory).
    #[arg(long, env = run::children::ENV_SCENARIO)]
    pub scenario: String,
    /// The run's iceoryx2 resource prefix.
    #[arg(long, env = run::children::ENV_PREFIX)]
    pub prefix: String,
    #[arg(long, value_enum, default_value = "lockstep", env = run::children::ENV_MODE)]
    pub mode: Mode,
    /// The producer epoch stamped on every sample.
    #[arg(long, default_value_t = 0, env = run::children::ENV_EPOCH)]
    pub epoch: u32,
    /// The robot whose pipeline the process is part of: its topics' services and the
    /// robot id of every sample.
    #[arg(long, default_value_t = protocol::FIRST_ROBOT, env = run::children::ENV_ROBOT)]
    pub robot: u32,
    /// The orchestrator's pid: when it is gone, the robot is stopped and the process exits.
    #[arg(long, env = run::children::ENV_SUPERVISOR)]
    pub supervisor_pid: Option<u32>,
    /// The iceoryx2 id of the orchestrator's control publisher (hexadecimal): control
    /// messages from any other publisher are refused.
    #[arg(long, env = run::children::ENV_CONTROL_PUBLISHER, value_parser = parse_hex_id)]
    pub control_publisher: Option<u128>,
    /// Override a value of the run's scenario for this process only, e.g.
    /// `mpc.horizon=10` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

#[derive(Debug, clap::Args)]
pub struct IdentifyArgs {
    #[arg(help = file_or_built_in_help())]
    pub scenario: Option<String>,
    /// Override a scenario value (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Forward speed of the excitation's steps and chirp, m/s.
    #[arg(long, default_value_t = 0.3)]
    pub speed: f64,
    /// Turn rate of the excitation's steps and chirp, rad/s.
    #[arg(long, default_value_t = 1.0)]
    pub turn: f64,
    /// The farthest the excitation may take the robot from its start, m.
    #[arg(long, default_value_t = 1.0)]
    pub within: f64,
}

#[derive(Debug, clap::Args)]
pub struct SweepArgs {
    #[arg(help = file_or_built_in_help())]
    pub scenario: Option<String>,
    /// An axis of the grid: a dotted key and its values, e.g. `mpc.gamma=0.1,0.3,0.5`
    /// (repeatable; every combination runs).
    #[arg(long = "grid", value_name = "KEY=V1,V2,...")]
    pub grid: Vec<String>,
    /// Override a scenario value for every run (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Noise seeds per combination (seeds 1..=N); 0 keeps the scenario's seed.
    #[arg(long, default_value_t = 0)]
    pub seeds: u64,
    /// Sweep directory [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Runs at a time [default: the number of cores].
    #[arg(long)]
    pub threads: Option<usize>,
    /// Write each run's `run.mcap` too (docs/foxglove.md).
    #[arg(long)]
    pub mcap: bool,
}

/// `scmpc fuzz --perception`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum FuzzPerception {
    Track,
    Lidar,
}

#[derive(Debug, clap::Args)]
pub struct FuzzArgs {
    /// Number of worlds.
    #[arg(long, default_value_t = 200)]
    pub count: usize,
    /// Seed of the batch (the same seed draws the same worlds).
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Override a value in every world, e.g. `plant.noise_variance=0.01` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Share of the worlds with people on the way (moving obstacles), 0 to 1 [default:
    /// 0.5; with `--robots` 0: on the robots' ways, docs/fleet.md, "Fuzz"].
    #[arg(long, value_name = "SHARE")]
    pub people: Option<f64>,
    /// How the robot perceives the obstacles: `track` (measured from the truth, the
    /// obstacles at rest in the map) or `lidar` (a lidar in every world, small obstacles at
    /// rest half the time not in the map).
    #[arg(long, value_enum, default_value_t = FuzzPerception::Track)]
    pub perception: FuzzPerception,
    /// Fleets of this many robots, `A..B` or `N` (docs/fleet.md, "Fuzz"): each world draws
    /// its number of robots from the range.
    #[arg(long, value_name = "A..B")]
    pub robots: Option<String>,
    /// Directory of fuzz.csv and the failed worlds [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Runs at a time [default: the number of cores].
    #[arg(long)]
    pub threads: Option<usize>,
}

#[derive(Debug, clap::Args)]
pub struct SwapArgs {
    /// Directory of the running run (its `run.json`).
    #[arg(long = "run", value_name = "DIR")]
    pub run_dir: PathBuf,
    /// Role to replace: estimator, mpc or dfl.
    pub role: String,
    /// Program and arguments of the replacement, after `--`, e.g.
    /// `-- scmpc mpc --set mpc.horizon=10`.
    #[arg(last = true, value_name = "COMMAND")]
    pub command: Vec<String>,
}

/// How this side secures its links to other hosts (docs/hosts.md).
#[derive(Debug, clap::Args)]
pub struct SecurityArgs {
    /// The CA certificate (PEM) both sides trust: TLS with mutual authentication.
    #[arg(long, value_name = "FILE", requires_all = ["tls_cert", "tls_key"])]
    pub tls_ca: Option<PathBuf>,
    /// This side's certificate (PEM), signed by the CA.
    #[arg(long, value_name = "FILE", requires_all = ["tls_ca", "tls_key"])]
    pub tls_cert: Option<PathBuf>,
    /// This side's private key (PEM).
    #[arg(long, value_name = "FILE", requires_all = ["tls_ca", "tls_cert"])]
    pub tls_key: Option<PathBuf>,
    /// Allow plain TCP to or from an address that is not on loopback.
    #[arg(long)]
    pub insecure: bool,
}

impl SecurityArgs {
    pub fn security(&self) -> Result<hosts::net::Security, CliError> {
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
pub struct HostArgs {
    /// The host's name, as scenarios place roles on it (`[hosts] mpc = "NAME"`).
    #[arg(long)]
    pub name: String,
    /// Where to listen: `tcp/ADDR:PORT` (loopback, or with --insecure) or `tls/ADDR:PORT`.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: String,
    #[command(flatten)]
    pub security: SecurityArgs,
}

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    #[arg(help = file_or_built_in_help())]
    pub scenario: Option<String>,
    /// Step every role's task in this process (deterministic; the reference for the other modes).
    #[arg(long)]
    pub in_process: bool,
    /// Override a scenario value by its dotted key, e.g. `mpc.gamma=0.3` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Run directory [default: a fresh directory under runs/].
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// iceoryx2 resource prefix of the run, to attach tools to it [default: a fresh one].
    #[arg(long, value_name = "PREFIX")]
    pub prefix: Option<String>,
    /// Clock of a multi-process run (`--in-process` is always lockstep).
    #[arg(long, value_enum, default_value = "lockstep")]
    pub mode: Mode,
    /// Do not write `run.mcap` (docs/foxglove.md).
    #[arg(long)]
    pub no_mcap: bool,
    /// Serve the run to Foxglove while it drives, on IP:PORT [default: 127.0.0.1:8765]
    /// (`live.address`; docs/foxglove.md, "Live").
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = protocol::DEFAULT_LIVE_ADDRESS)]
    pub live: Option<String>,
    /// Lockstep with a live view: hold the clock to real time (`live.pace`).
    #[arg(long)]
    pub live_pace: bool,
    /// Real time: keep every core busy at idle priority for the run, so that no core
    /// halts between samples (faster wake-ups and steps on a virtual machine, at the cost
    /// of all idle CPU; docs/performance.md, "Idle cores").
    #[arg(long)]
    pub keep_cores_awake: bool,
    /// Where the agent of a host the scenario places roles on listens, e.g.
    /// `compute=tcp/127.0.0.1:7447` (repeatable; overrides `[hosts.endpoints]`).
    #[arg(long = "host", value_name = "NAME=ENDPOINT")]
    pub hosts: Vec<String>,
    #[command(flatten)]
    pub security: SecurityArgs,
}

impl RunArgs {
    /// The `--set` overrides, then those `--live` and `--live-pace` stand for.
    pub fn all_overrides(&self) -> Vec<String> {
        let live = (self.live.iter()).map(|address| format!("live.address={address}"));
        let pace = self.live_pace.then(|| "live.pace=true".to_string());
        (self.overrides.iter().cloned())
            .chain(live)
            .chain(pace)
            .collect()
    }
}

/// An iceoryx2 port id as printed by iceoryx2 (hexadecimal).
fn parse_hex_id(text: &str) -> Result<u128, String> {
    u128::from_str_radix(text, 16).map_err(|e| format!("`{text}` is not a hexadecimal id: {e}"))
}
