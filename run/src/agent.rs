//! `scmpc host`: the agent of a host (docs/hosts.md), a long-lived process that serves run
//! after run. An orchestrator asks it to join a run; it then runs the roles the scenario
//! places on its host as ordinary role processes on an iceoryx2 prefix of its own, runs
//! the host's bridge, starts, signals and reaps the processes as the orchestrator says,
//! reports their exits, and at the end of the run (or when the orchestrator is gone)
//! stops them and removes the run's resources. Its role processes take the run's id, and
//! a clock corrected to the orchestrator's. In a fleet's run it joins once for each robot
//! placed on its host, each join a run of its own here (its prefix, bridge and processes).

use crate::children::Children;
use anyhow::{Context, anyhow};
use hosts::auth::RunKey;
use hosts::bridge::{Bridge, BridgeSpec, LinkFaults};
use hosts::keys::{self, ORCHESTRATOR};
use hosts::messages::{self, CommandReply, Exit, HostCommand, JoinReply, JoinRequest};
use hosts::net::{self, Security};
use protocol::endpoint::Endpoint;
use protocol::{Role, Scenario};
use runtime::clock::{ENV_CLOCK_CORRECTION_NS, RunMode};
use runtime::ipc::{self, CONTROL, ENV_RUN_ID};
use runtime::process::ORPHAN_GRACE;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};
use zenoh::Wait;
use zenoh::sample::SampleKind;

/// How long the agent waits for a join request at a time while it serves no run.
const POLL: Duration = Duration::from_millis(20);
/// The start of the name of a run's directory (the scenario file) of an agent:
/// `scmpc-host-<agent pid>-<host>-<run>`, under the temporary directory.
const RUN_DIR_STEM: &str = "scmpc-host-";

/// Removes the run directories of agents that are dead (SIGKILLed, say).
fn remove_dead_run_dirs() {
    let Ok(entries) = std::fs::read_dir(std::env::temp_dir()) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let pid = name
            .strip_prefix(RUN_DIR_STEM)
            .and_then(|rest| rest.split('-').next())
            .and_then(|pid| pid.parse::<u32>().ok());
        if pid.is_some_and(|pid| !ipc::process_alive(pid)) {
            let _ = std::fs::remove_dir_all(entry.path());
        }
    }
}

/// How long after joining the orchestrator's liveliness token must have been seen.
const ORCHESTRATOR_TOKEN_TIMEOUT: Duration = Duration::from_secs(5);
/// How long role processes have to exit at the end of a run before they are killed.
const STOP_TIMEOUT: Duration = Duration::from_secs(2);

/// How often the agent looks at its runs' commands and processes while it serves any.
const RUN_POLL: Duration = Duration::from_millis(5);

/// Serves runs on `listen` as host `name` until `stop`: one run at a time, and in it as
/// many of a fleet's robots as the run places here (one join each, with its own processes,
/// iceoryx2 prefix and bridge).
pub fn serve(
    name: &str,
    listen: &Endpoint,
    security: &Security,
    stop: &AtomicBool,
) -> anyhow::Result<()> {
    crate::multiproc::remove_dead_runs();
    remove_dead_run_dirs();
    let session = net::open(net::config(std::slice::from_ref(listen), &[], security)?)?;
    let joins = session
        .declare_queryable(keys::agent_join(name))
        .wait()
        .map_err(|e| anyhow!("zenoh: {e}"))?;
    eprintln!(
        "scmpc host `{name}`: listening on {} (pid {})",
        listen.zenoh(),
        std::process::id()
    );
    let mut runs: Vec<HostRun> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let query = match runs.is_empty() {
            true => joins.recv_timeout(POLL).ok().flatten(),
            false => joins.try_recv().ok().flatten(),
        };
        if let Some(run) = query.and_then(|q| join(&session, name, &runs, q)) {
            runs.push(run);
        }
        let mut i = 0;
        while i < runs.len() {
            match runs[i].poll(stop) {
                Some(ended) => {
                    let run = runs.swap_remove(i);
                    let (id, robot) = (run.run.clone(), run.robot);
                    run.end();
                    eprintln!("scmpc host `{name}`: run {id} (robot {robot}) ended ({ended})");
                }
                None => i += 1,
            }
        }
        if !runs.is_empty() {
            std::thread::sleep(RUN_POLL);
        }
    }
    for run in runs {
        run.end();
    }
    Ok(())
}

/// Answers the join request `query`: the run it joined, or `None` (refused, with why).
/// While it serves a run it joins only more robots of that run (`run_id`).
fn join(
    session: &zenoh::Session,
    name: &str,
    runs: &[HostRun],
    query: zenoh::query::Query,
) -> Option<HostRun> {
    let refuse = |query, error: String| {
        messages::answer(
            query,
            &JoinReply {
                error,
                ..JoinReply::default()
            },
        )
    };
    let request: JoinRequest = match messages::request_of(&query) {
        Ok(r) => r,
        Err(e) => {
            refuse(query, e);
            return None;
        }
    };
    if let Some(busy) = runs.iter().find(|r| r.run_id != request.run_id) {
        refuse(query, format!("busy with run {}", busy.run));
        return None;
    }
    if runs.iter().any(|r| r.run == request.run) {
        refuse(query, format!("joined run {} already", request.run));
        return None;
    }
    match HostRun::join(session, name, &request) {
        Ok(run) => {
            messages::answer(query, &run.reply());
            eprintln!(
                "scmpc host `{name}`: joined run {} (robot {})",
                request.run, request.robot
            );
            Some(run)
        }
        Err(e) => {
            let error = format!("{e:#}");
            eprintln!("scmpc host `{name}`: refused run {}: {error}", request.run);
            refuse(query, error);
            None
        }
    }
}

/// A run this host has joined.
struct HostRun {
    name: String,
    /// The run's key chunk (a fleet's robot's own: [`hosts::keys::fleet_robot_run`]).
    run: String,
    /// The run's id, the same for every robot of a fleet.
    run_id: u32,
    robot: u32,
    /// When it joined, whether the orchestrator's token has been seen since, and when it
    /// went away.
    joined: Instant,
    orchestrator_seen: bool,
    orchestrator_gone: Option<Instant>,
    prefix: String,
    dir: PathBuf,
    clock: hosts::clock_sync::ClockLink,
    children: Children,
    commands: zenoh::query::Queryable<zenoh::handlers::FifoChannelHandler<zenoh::query::Query>>,
    exits: zenoh::pubsub::Publisher<'static>,
    orchestrator:
        zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    _token: zenoh::liveliness::LivelinessToken,
    /// Declared after the ports: dropped (stopped) after them.
    bridge: Bridge,
}

impl HostRun {
    /// What a join request asks of host `name`, checked: the scenario (validated as the
    /// orchestrator's was), the clock, the roles and the run's key.
    fn checked(
        name: &str,
        r: &JoinRequest,
    ) -> anyhow::Result<(protocol::Validated, RunMode, Vec<Role>, RunKey)> {
        if r.host != name {
            return Err(anyhow!("this is host `{name}`, not `{}`", r.host));
        }
        let scenario = Scenario::from_toml(&r.scenario_toml, "the orchestrator's scenario")
            .and_then(|s| s.validated("the orchestrator's scenario"))
            .map_err(|e| anyhow!("{e}"))?;
        let mode = match r.mode.as_str() {
            "lockstep" => RunMode::Lockstep,
            "realtime" => RunMode::Realtime,
            other => return Err(anyhow!("no clock `{other}`")),
        };
        let roles = r
            .roles
            .iter()
            .map(|n| Role::from_name(n).ok_or_else(|| anyhow!("no role `{n}`")))
            .collect::<anyhow::Result<Vec<Role>>>()?;
        let key = RunKey::from_hex(&r.key).ok_or_else(|| anyhow!("a malformed run key"))?;
        Ok((scenario, mode, roles, key))
    }

    /// The run's directory on this host, with the scenario's file the role processes
    /// read.
    fn run_dir(
        name: &str,
        r: &JoinRequest,
        scenario: &protocol::Validated,
    ) -> anyhow::Result<(std::path::PathBuf, std::path::PathBuf)> {
        let dir = std::env::temp_dir().join(format!(
            "{RUN_DIR_STEM}{}-{name}-{}",
            std::process::id(),
            r.run
        ));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        let scenario_file = dir.join("scenario.toml");
        std::fs::write(&scenario_file, scenario.to_toml())
            .with_context(|| format!("writing {}", scenario_file.display()))?;
        Ok((dir, scenario_file))
    }

    /// The bridge of host `name`, on `prefix`, in the run of `r`, whose key is `key`, for
    /// the roles on it.
    fn bridge_spec(
        name: &str,
        r: &JoinRequest,
        scenario: &Scenario,
        mode: RunMode,
        prefix: &str,
        key: RunKey,
        roles: Vec<Role>,
    ) -> BridgeSpec {
        BridgeSpec {
            run: r.run.clone(),
            host: name.to_string(),
            prefix: prefix.to_string(),
            robot: r.robot,
            key,
            send: r
                .send
                .iter()
                .map(|t| (t.clone(), vec![ORCHESTRATOR.to_string()]))
                .collect(),
            receive: r.receive.clone(),
            peer_send: Default::default(),
            peer_receive: r.peer_receive.clone(),
            local_roles: Some(roles),
            control_publisher: None,
            faults: LinkFaults::of(
                scenario,
                scenario.seed ^ u64::from(ipc::run_id(name.as_bytes())),
            ),
            carrier_priority: crate::scheduling::bridge_priority(&scenario.realtime, mode),
        }
    }

    /// Joins the run of `r` as host `name`: the clock exchange, the run's directory, the
    /// bridge, the processes' environment, and the topics of commands, exits and liveliness.
    fn join(session: &zenoh::Session, name: &str, r: &JoinRequest) -> anyhow::Result<HostRun> {
        let (scenario, mode, roles, key) = Self::checked(name, r)?;
        // The topics it opens make room for every robot of a fleet, as everywhere else.
        ipc::admit_robots(scenario.robot_count());
        let clock = hosts::clock_sync::estimate(session, &r.run)?;
        let prefix = ipc::new_prefix();
        let (dir, scenario_file) = Self::run_dir(name, r, &scenario)?;
        ipc::register_run(&prefix, &dir).context("registering the run")?;
        // A fleet's robot's faults are its own (`robots.<i>.fault`).
        let member = scenario.member(r.robot as usize);
        let spec = Self::bridge_spec(name, r, &member, mode, &prefix, key, roles);
        let bridge = Bridge::start(session, spec)?;
        let control = bridge
            .relay_id(CONTROL)
            .ok_or_else(|| anyhow!("the run sends no control to this host"))?;
        let children = Children::new(
            &scenario_file,
            &prefix,
            r.robot,
            mode,
            control,
            vec![
                (ENV_RUN_ID.to_string(), format!("{:x}", r.run_id)),
                (
                    ENV_CLOCK_CORRECTION_NS.to_string(),
                    clock.correction_ns.to_string(),
                ),
            ],
            None,
        )?;
        let zenoh_error = |e: zenoh::Error| anyhow!("zenoh: {e}");
        let commands = session
            .declare_queryable(keys::host_command(&r.run, name))
            .wait()
            .map_err(zenoh_error)?;
        let exits = session
            .declare_publisher(keys::host_exits(&r.run, name))
            .wait()
            .map_err(zenoh_error)?;
        let orchestrator = session
            .liveliness()
            .declare_subscriber(keys::alive(&r.run, ORCHESTRATOR))
            .history(true)
            .wait()
            .map_err(zenoh_error)?;
        let token = session
            .liveliness()
            .declare_token(keys::alive(&r.run, name))
            .wait()
            .map_err(zenoh_error)?;
        Ok(HostRun {
            name: name.to_string(),
            run: r.run.clone(),
            run_id: r.run_id,
            robot: r.robot,
            joined: Instant::now(),
            orchestrator_seen: false,
            orchestrator_gone: None,
            prefix,
            dir,
            clock,
            children,
            commands,
            exits,
            orchestrator,
            _token: token,
            bridge,
        })
    }

    fn reply(&self) -> JoinReply {
        JoinReply {
            error: String::new(),
            agent_pid: std::process::id(),
            prefix: self.prefix.clone(),
            clock: self.clock,
        }
    }

    /// Serves the run for a moment: its processes' exits and the orchestrator's commands.
    /// Says why the run is over, when it is: its end, the orchestrator's loss, or `stop`.
    fn poll(&mut self, stop: &AtomicBool) -> Option<&'static str> {
        if stop.load(Ordering::Relaxed) {
            return Some("the agent was stopped");
        }
        while let Ok(Some(sample)) = self.orchestrator.try_recv() {
            match sample.kind() {
                SampleKind::Put => self.orchestrator_seen = true,
                SampleKind::Delete => {
                    self.orchestrator_gone.get_or_insert_with(Instant::now);
                }
            }
        }
        // An orchestrator that gave up on the join before this host answered never shows
        // its token here: without it the run is over as well.
        if !self.orchestrator_seen && self.joined.elapsed() >= ORCHESTRATOR_TOKEN_TIMEOUT {
            self.orchestrator_gone.get_or_insert_with(Instant::now);
        }
        // Without its orchestrator a real-time robot brakes for the orphan grace; the
        // processes of this host then stop.
        if (self.orchestrator_gone).is_some_and(|t| t.elapsed() >= ORPHAN_GRACE) {
            return Some("the orchestrator is gone");
        }
        while let Some((p, status)) = self.children.take_exited() {
            let _ = ipc::cleanup_dead_nodes(&self.prefix);
            let exit = Exit {
                role: p.role.as_str().to_string(),
                epoch: p.epoch,
                pid: p.pid(),
                status,
            };
            if let Ok(bytes) = serde_json::to_vec(&exit) {
                let _ = self.exits.put(bytes).wait();
            }
        }
        self.children.kill_overdue();
        while let Ok(Some(query)) = self.commands.try_recv() {
            let command: Result<HostCommand, String> = messages::request_of(&query);
            let ended = matches!(command, Ok(HostCommand::End));
            let reply = match command {
                Ok(c) => self.execute(c),
                Err(error) => CommandReply {
                    error,
                    ..CommandReply::default()
                },
            };
            messages::answer(query, &reply);
            if ended {
                return Some("the orchestrator ended it");
            }
        }
        None
    }

    fn execute(&mut self, command: HostCommand) -> CommandReply {
        let role_of = |name: &str| Role::from_name(name).ok_or_else(|| format!("no role `{name}`"));
        let result = match command {
            HostCommand::Spawn {
                role,
                epoch,
                command,
            } => role_of(&role).and_then(|role| {
                self.children
                    .spawn_role(role, epoch, &command)
                    .map_err(|e| format!("{e:#}"))
            }),
            HostCommand::Terminate { role, epoch } => role_of(&role).map(|role| {
                let pid = self.children.pid(role, epoch).unwrap_or(0);
                self.children.retire(role, epoch, STOP_TIMEOUT);
                pid
            }),
            HostCommand::Kill { role, epoch } => {
                role_of(&role).map(|role| self.children.kill_running(role, epoch).unwrap_or(0))
            }
            HostCommand::End => {
                self.stop_processes();
                return CommandReply {
                    link: self.bridge.counters(),
                    ..CommandReply::default()
                };
            }
        };
        match result {
            Ok(pid) => CommandReply {
                pid,
                ..CommandReply::default()
            },
            Err(error) => CommandReply {
                error,
                ..CommandReply::default()
            },
        }
    }

    fn stop_processes(&mut self) {
        for p in &self.children.list {
            if let crate::children::Handle::Local(child) = &p.handle
                && let Ok(pid) = libc::pid_t::try_from(child.id())
            {
                // SAFETY: kill(2) on the pid of a child not reaped yet.
                unsafe { libc::kill(pid, libc::SIGTERM) };
            }
        }
        self.children.shut_down(STOP_TIMEOUT);
    }

    /// Stops what still runs and removes the run's resources; the agent goes on.
    fn end(mut self) {
        self.stop_processes();
        let (prefix, dir, name) = (self.prefix.clone(), self.dir.clone(), self.name.clone());
        drop(self);
        if let Err(e) = ipc::remove_run(&prefix) {
            eprintln!("scmpc host `{name}`: removing the run's resources: {e}");
        }
        let _ = std::fs::remove_dir_all(dir);
    }
}
