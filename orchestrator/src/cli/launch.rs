//! The commands that run roles: `scmpc run`, a role process (`scmpc mpc`, ...) and a
//! host's agent (`scmpc host`).

use super::args::{HostArgs, Mode, RoleArgs, RunArgs};
use super::{CliError, CliResult, bad_input};
use anyhow::Context;
use protocol::Role;
use run::{inprocess, multiproc, scenarios};
use runtime::clock::RunMode;
use runtime::process::ProcessArgs;

/// Runs one role process until the orchestrator stops it.
pub(super) fn role(args: RoleArgs, this: Role) -> CliResult {
    // A replacement command that starts the wrong role would only be refused, sample by
    // sample, as the wrong epoch: say so at once.
    if let Ok(wanted) = std::env::var(run::children::ENV_ROLE)
        && wanted != this.as_str()
    {
        return Err(bad_input(format!(
            "this is the {} process, but the run started it as its {wanted} ({})",
            this.as_str(),
            run::children::ENV_ROLE
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
    // A fleet's processes read the fleet's scenario and drive their robot's member.
    let scenario = match scenario.is_fleet() {
        true => (scenario.member(args.robot as usize))
            .validated(&format!("robot {} of the fleet", args.robot))
            .map_err(|e| bad_input(e.to_string()))?,
        false => scenario,
    };
    let process_args = ProcessArgs {
        scenario,
        prefix: args.prefix.clone(),
        mode: args.mode.into(),
        epoch: args.epoch,
        robot: args.robot,
        supervisor_pid: args.supervisor_pid,
        control_publisher: args.control_publisher,
    };
    let result = run::roles::serve(this, &process_args);
    // Orphaned (the orchestrator or the host's agent is dead): the last process of the run
    // to exit removes the run's resources, as nobody else will until the next run or agent
    // starts on this machine.
    if args
        .supervisor_pid
        .is_some_and(|pid| !runtime::ipc::process_alive(pid))
    {
        let _ = runtime::ipc::remove_run(&args.prefix);
    }
    result.map_err(|e| CliError::Failed(e.into()))
}

/// Whether `args` ask for a clock the run can have: a ROS 2 robot (`robot`) is driven in
/// real time only, in-process runs are lockstep.
fn check_modes(args: &RunArgs, robot: bool) -> CliResult {
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
    if robot && (args.in_process || args.mode != Mode::Realtime) {
        return Err(bad_input(
            "plant.kind = \"ros2\": a robot is driven in real time only \
             (give --mode realtime, without --in-process)",
        ));
    }
    Ok(())
}

/// `scmpc run`; `quiet` (`-q`): no status or progress lines.
pub(super) fn run(args: RunArgs, quiet: bool) -> CliResult {
    let scenario =
        scenarios::load(args.scenario.as_deref(), &args.all_overrides()).map_err(bad_input)?;
    scenarios::check_swap_programs(&scenario).map_err(bad_input)?;
    let robot = scenario.plant.kind == protocol::PlantKind::Ros2;
    check_modes(&args, robot)?;
    if scenario.is_fleet() {
        return run_fleet(scenario, args, quiet);
    }
    let out = args
        .out
        .unwrap_or_else(|| record::run_dir::default_run_dir(&scenario.name));
    if args.mode == Mode::Realtime {
        run::scheduling::check(&scenario.realtime).map_err(bad_input)?;
    }
    let prefix = args.prefix.unwrap_or_else(runtime::ipc::new_prefix);
    runtime::ipc::run_config(&prefix).map_err(|e| bad_input(format!("--prefix: {e}")))?;
    let security = args.security.security()?;
    if robot {
        protocol::endpoint::Endpoint::parse(&scenario.ros2.endpoint)
            .and_then(|e| security.allows(&e))
            .map_err(|e| bad_input(format!("ros2.endpoint: {e}")))?;
    }
    let hosts = if args.in_process {
        multiproc::HostsSetup::default()
    } else {
        hosts_setup(&scenario, &args.hosts, security.clone(), args.mode.into())?
    };
    let stop = run::stop::on_signals();
    let scenario = if robot {
        from_the_robot(scenario, &security, &stop)?
    } else {
        scenario
    };
    let awake = args
        .keep_cores_awake
        .then(run::awake::AwakeCores::start)
        .transpose()
        .context("keeping the cores awake")?;
    println!("run directory: {}", out.display());
    let recording = run::sinks::Recording {
        mcap: !args.no_mcap,
        status_line: !quiet,
        live: scenario.live.is_some(),
    };
    let summary = if args.in_process {
        inprocess::run(&scenario, &out, recording, &stop)
    } else {
        multiproc::run(
            &scenario,
            &out,
            args.mode.into(),
            &prefix,
            &hosts,
            recording,
            &stop,
        )
    }
    .with_context(|| format!("run of `{}`", scenario.name))?;
    drop(awake);
    if let Err(e) = study::figures::run_plots(&out, &scenario) {
        eprintln!("warning: no plots for the run: {e:#}");
    }
    print!("{}", summary.table());
    if summary.outcome == record::judge::Outcome::Reached {
        Ok(())
    } else {
        Err(CliError::NotReached)
    }
}

/// `scmpc run` of a fleet (`[[robots]]`, docs/fleet.md): in process, or as role processes
/// in lockstep or in real time.
fn run_fleet(scenario: protocol::Validated, args: RunArgs, quiet: bool) -> CliResult {
    if args.mode == Mode::Realtime {
        run::scheduling::check(&scenario.realtime).map_err(bad_input)?;
    }
    let prefix = (args.prefix.clone()).unwrap_or_else(runtime::ipc::new_prefix);
    runtime::ipc::run_config(&prefix).map_err(|e| bad_input(format!("--prefix: {e}")))?;
    let out =
        (args.out.clone()).unwrap_or_else(|| record::run_dir::default_run_dir(&scenario.name));
    let hosts = match args.in_process {
        true => multiproc::HostsSetup::default(),
        false => {
            let security = args.security.security()?;
            hosts_setup(&scenario, &args.hosts, security, args.mode.into())?
        }
    };
    let stop = run::stop::on_signals();
    println!("run directory: {}", out.display());
    let recording = run::sinks::Recording {
        mcap: !args.no_mcap,
        status_line: !quiet,
        live: scenario.live.is_some(),
    };
    let summary = match args.in_process {
        true => run::fleet::run(&scenario, &out, recording, &stop),
        false => {
            let awake = (args.keep_cores_awake)
                .then(run::awake::AwakeCores::start)
                .transpose()
                .context("keeping the cores awake")?;
            let mode = args.mode.into();
            let ran =
                multiproc::fleet::run(&scenario, &out, (mode, &prefix), &hosts, recording, &stop);
            drop(awake);
            ran
        }
    }
    .with_context(|| format!("run of the fleet `{}`", scenario.name))?;
    if let Err(e) = study::figures::fleet_plots(&out, &scenario) {
        eprintln!("warning: no plots for the run: {e:#}");
    }
    if !quiet {
        print!("{}", summary.table());
    }
    match summary.all_reached() {
        true => Ok(()),
        false => Err(CliError::NotReached),
    }
}

/// `scenario` starting where the ROS 2 robot's first odometry puts it, and going to the
/// goal its goal topic gave (`ros2.wait_for_goal`; docs/ros2.md). Nothing runs yet.
fn from_the_robot(
    scenario: protocol::Validated,
    security: &hosts::net::Security,
    stop: &std::sync::atomic::AtomicBool,
) -> Result<protocol::Validated, CliError> {
    if scenario.ros2.wait_for_goal {
        eprintln!(
            "waiting for a goal on `{}` (RViz: \"2D Goal Pose\")",
            scenario.ros2.goal_topic
        );
    }
    let lidar = scenario.lidar.is_some();
    let start = robot::first_contact(&scenario.ros2, security, lidar, stop)
        .context("the ROS 2 robot (plant.kind = \"ros2\")")?;
    let mut moved = scenario.into_inner();
    moved.robot.start = start.pose;
    if let Some(goal) = start.goal {
        // Its heading is turned to only by a robot that settles at its goal.
        let settles = moved.robot.final_approach == protocol::FinalApproach::Settle;
        moved.robot.goal = protocol::Goal {
            yaw_rad: goal.yaw_rad.filter(|_| settles),
            ..goal
        };
    }
    moved
        .validated("the robot's first odometry")
        .map_err(bad_input)
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
    let used = scenario.host_names();
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
    // A fleet's robot's own faults act on its links too (`robots.<i>.fault`).
    let own = (scenario.robots.iter()).filter_map(|r| r.fault.as_ref());
    let link_faults = std::iter::once(&scenario.fault)
        .chain(own)
        .any(protocol::FaultConfig::acts_on_links);
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
pub(super) fn host(args: HostArgs) -> CliResult {
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
    let stop = run::stop::on_signals();
    run::agent::serve(&args.name, &listen, &security, &stop)?;
    Ok(())
}
