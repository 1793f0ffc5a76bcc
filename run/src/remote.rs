//! The orchestrator's side of a run whose roles are placed on other hosts (docs/hosts.md):
//! it asks each host's agent to join the run (within `hosts.join_timeout_s`, or the run fails
//! before tick 0 naming the host), runs the bridge of its own host, starts and signals
//! role processes through the agents, hears their exits, and notices a host that is
//! gone (its liveliness token goes away).

use anyhow::{Context, anyhow};
use hosts::auth::RunKey;
use hosts::bridge::{Bridge, BridgeSpec, LinkFaults};
use hosts::clock_sync::ClockLink;
use hosts::keys::{self, ORCHESTRATOR};
use hosts::messages::{self, CommandReply, Exit, HostCommand, JoinReply, JoinRequest};
use hosts::net::{self, Security};
use hosts::{LinkCounters, routes};
use protocol::endpoint::Endpoint;
use protocol::{Role, Validated};
use runtime::clock::RunMode;
use runtime::ipc::{self, output_topic};
use std::cell::RefCell;
use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};
use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};

/// How long a host's agent has to answer the join request.
/// How long an agent has to answer a command.
const COMMAND_TIMEOUT: Duration = Duration::from_secs(3);

/// One other host of the run, as it joined.
#[derive(Debug, Clone)]
pub struct HostLink {
    pub endpoint: String,
    pub agent_pid: u32,
    /// Its iceoryx2 prefix for the run.
    pub prefix: String,
    pub clock: ClockLink,
}

/// A role process's exit, as its host's agent reported it.
#[derive(Debug, Clone)]
pub struct RemoteExit {
    pub host: String,
    pub role: String,
    pub epoch: u32,
    pub status: String,
}

/// The other hosts of a run.
pub struct RemoteHosts {
    run: String,
    /// Where each role runs (the scenario's `[hosts]`).
    placement: protocol::HostsConfig,
    pub hosts: BTreeMap<String, HostLink>,
    /// Hosts that were lost.
    lost: RefCell<BTreeSet<String>>,
    bridge: Bridge,
    exits: Subscribed,
    alive: Subscribed,
    _clock: zenoh::query::Queryable<()>,
    _token: zenoh::liveliness::LivelinessToken,
    /// Declared last: closed after everything above.
    session: zenoh::Session,
}

/// A Zenoh subscriber whose samples queue until taken.
type Subscribed = Subscriber<FifoChannelHandler<Sample>>;

/// The orchestrator's liveliness token in `run`, and its subscribers to the hosts' exit
/// reports and liveliness tokens.
fn watch_hosts(
    session: &zenoh::Session,
    run: &str,
) -> anyhow::Result<(zenoh::liveliness::LivelinessToken, Subscribed, Subscribed)> {
    let token = session
        .liveliness()
        .declare_token(keys::alive(run, ORCHESTRATOR))
        .wait()
        .map_err(|e| anyhow!("zenoh: declaring the orchestrator's token: {e}"))?;
    let exits = session
        .declare_subscriber(keys::host_exits(run, "*"))
        .wait()
        .map_err(|e| anyhow!("zenoh: subscribing to exits: {e}"))?;
    let alive = session
        .liveliness()
        .declare_subscriber(keys::alive_all(run))
        .history(true)
        .wait()
        .map_err(|e| anyhow!("zenoh: subscribing to the hosts' tokens: {e}"))?;
    Ok((token, exits, alive))
}

/// The robot whose roles other hosts run: a run's one robot, or one of a fleet's.
#[derive(Debug, Clone, Copy)]
pub struct Whose<'a> {
    pub robot: u32,
    /// The fleet's scenario, which every process reads (`None`: a run of one robot).
    pub fleet: Option<&'a Validated>,
}

impl Whose<'_> {
    /// The key chunk of the run on `prefix` for this robot's links: a fleet's robot's own
    /// ([`keys::fleet_robot_run`]), so that two robots on one host never meet.
    fn run_key(&self, prefix: &str) -> String {
        match self.fleet {
            Some(_) => keys::fleet_robot_run(prefix, self.robot),
            None => keys::run_of_prefix(prefix),
        }
    }

    /// The other robots' topics the host of the robot's tracker takes, by robot and topic
    /// (docs/fleet.md, "Across hosts").
    fn peer_topics(&self) -> Vec<(u32, String)> {
        let robots = self.fleet.map_or(1, |f| f.robot_count() as u32);
        (0..robots)
            .filter(|other| *other != self.robot)
            .flat_map(|other| {
                let topics = protocol::graph::peer_inputs_of(protocol::Role::Tracker);
                topics.iter().map(move |t| (other, t.to_string()))
            })
            .collect()
    }
}

impl RemoteHosts {
    /// Joins every host the scenario (`whose` robot's) places a role on, at `endpoints`,
    /// for the run on `prefix` whose control publisher is `control_publisher`; starts
    /// this host's bridge.
    pub fn connect(
        scenario: &Validated,
        mode: RunMode,
        prefix: &str,
        whose: Whose,
        endpoints: &BTreeMap<String, Endpoint>,
        security: &Security,
        control_publisher: u128,
    ) -> anyhow::Result<RemoteHosts> {
        let run = whose.run_key(prefix);
        let key = RunKey::generate().map_err(|e| anyhow!(e))?;
        let names = scenario.hosts.names();
        let connect: Vec<Endpoint> = names.iter().map(|n| endpoints[n].clone()).collect();
        let session = net::open(net::config(&[], &connect, security)?)?;
        let clock = hosts::clock_sync::serve(&session, &run)?;
        let (token, exits, alive) = watch_hosts(&session, &run)?;
        let running: Vec<Role> = scenario.roles().collect();
        let placement = scenario.hosts.clone();
        let routes = routes::plan(&protocol::graph::Graph::of(scenario), |r| placement.of(r));
        // A fleet's robot's tracker takes the other robots' samples where it runs.
        let (peers, peers_to) = match placement.of(Role::Tracker) {
            Some(host) => (whose.peer_topics(), vec![host.to_string()]),
            None => (Vec::new(), Vec::new()),
        };
        let bridge = Bridge::start(
            &session,
            BridgeSpec {
                run: run.clone(),
                host: ORCHESTRATOR.to_string(),
                prefix: prefix.to_string(),
                robot: whose.robot,
                key: key.clone(),
                send: routes.orchestrator_sends.clone(),
                receive: routes.orchestrator_receives.clone(),
                peer_send: (peers.iter().map(|p| (p.clone(), peers_to.clone()))).collect(),
                peer_receive: Vec::new(),
                local_roles: None,
                control_publisher: Some(control_publisher),
                faults: LinkFaults::of(scenario, scenario.seed),
                carrier_priority: crate::scheduling::bridge_priority(&scenario.realtime, mode),
            },
        )?;
        let mut hosts = BTreeMap::new();
        for name in names {
            let request = JoinRequest {
                run: run.clone(),
                run_id: ipc::run_id(prefix.as_bytes()),
                key: key.to_hex(),
                host: name.clone(),
                mode: mode.as_str().to_string(),
                robot: whose.robot,
                scenario_toml: whose.fleet.unwrap_or(scenario).to_toml(),
                roles: running
                    .iter()
                    .filter(|r| placement.of(**r) == Some(name.as_str()))
                    .map(|r| r.as_str().to_string())
                    .collect(),
                send: routes.host_sends.get(&name).cloned().unwrap_or_default(),
                receive: routes.host_receives.get(&name).cloned().unwrap_or_default(),
                peer_receive: match peers_to.contains(&name) {
                    true => peers.clone(),
                    false => Vec::new(),
                },
            };
            let timeout = scenario.hosts.join_timeout();
            let link = join_host(&session, &name, &request, timeout, endpoints[&name].zenoh())?;
            hosts.insert(name, link);
        }
        Ok(RemoteHosts {
            run,
            placement,
            hosts,
            lost: RefCell::default(),
            bridge,
            exits,
            alive,
            _clock: clock,
            _token: token,
            session,
        })
    }

    /// The host `role` runs on now (`None`: this one, also once its host was lost).
    pub fn host_of(&self, role: Role) -> Option<&str> {
        self.placement
            .of(role)
            .filter(|h| !self.lost.borrow().contains(*h))
    }

    /// The host the scenario places `role` on, lost or not.
    pub fn placed_on(&self, role: Role) -> Option<&str> {
        self.placement.of(role)
    }

    /// The publishers a process of `role` on another host is pinned to here: this host's
    /// relays of its outputs.
    pub fn pins(&self, role: Role) -> [u128; 2] {
        std::array::from_fn(|slot| {
            output_topic(role, slot)
                .and_then(|t| self.bridge.relay_id(t))
                .unwrap_or(0)
        })
    }

    fn command(&self, host: &str, command: &HostCommand) -> anyhow::Result<CommandReply> {
        let reply: CommandReply = messages::ask(
            &self.session,
            &keys::host_command(&self.run, host),
            command,
            COMMAND_TIMEOUT,
        )
        .with_context(|| format!("host `{host}`"))?;
        if reply.error.is_empty() {
            Ok(reply)
        } else {
            Err(anyhow!("host `{host}`: {}", reply.error))
        }
    }

    /// Starts `role` with producer `epoch` on `host` (`command` as for a local process).
    pub fn spawn(
        &self,
        host: &str,
        role: Role,
        epoch: u32,
        command: &[String],
    ) -> anyhow::Result<u32> {
        let reply = self.command(
            host,
            &HostCommand::Spawn {
                role: role.as_str().to_string(),
                epoch,
                command: command.to_vec(),
            },
        )?;
        Ok(reply.pid)
    }

    /// Asks the process of `role` and `epoch` on `host` to exit (SIGTERM).
    pub fn terminate(&self, host: &str, role: Role, epoch: u32) {
        let role = role.as_str().to_string();
        if let Err(e) = self.command(host, &HostCommand::Terminate { role, epoch }) {
            tracing::warn!("{e:#}");
        }
    }

    /// Kills the process of `role` and `epoch` on `host`.
    pub fn kill(&self, host: &str, role: Role, epoch: u32) {
        let role = role.as_str().to_string();
        if let Err(e) = self.command(host, &HostCommand::Kill { role, epoch }) {
            tracing::warn!("{e:#}");
        }
    }

    /// An exit an agent reported since the last call.
    pub fn take_exit(&self) -> Option<RemoteExit> {
        while let Ok(Some(sample)) = self.exits.try_recv() {
            let host = sample.key_expr().as_str().rsplit('/').nth(1)?.to_string();
            if let Ok(exit) = serde_json::from_slice::<Exit>(&sample.payload().to_bytes()) {
                return Some(RemoteExit {
                    host,
                    role: exit.role,
                    epoch: exit.epoch,
                    status: exit.status,
                });
            }
        }
        None
    }

    /// A host whose agent is gone (its token went away), once.
    pub fn take_lost(&self) -> Option<String> {
        while let Ok(Some(sample)) = self.alive.try_recv() {
            if sample.kind() != SampleKind::Delete {
                continue;
            }
            let host = sample.key_expr().as_str().rsplit('/').next()?.to_string();
            if self.hosts.contains_key(&host) && self.lost.borrow_mut().insert(host.clone()) {
                return Some(host);
            }
        }
        None
    }

    /// Whether `host`'s agent went away during the run.
    pub fn is_lost(&self, host: &str) -> bool {
        self.lost.borrow().contains(host)
    }

    /// Ends the run on every host that is still there: its agent stops its processes and
    /// removes the run's resources. Returns what every link carried, by host (the
    /// orchestrator's bridge under [`ORCHESTRATOR`]).
    pub fn end(&self) -> BTreeMap<String, LinkCounters> {
        // A host lost after the driver last looked is not asked.
        while self.take_lost().is_some() {}
        let mut links = BTreeMap::from([(ORCHESTRATOR.to_string(), self.bridge.counters())]);
        for host in self.hosts.keys() {
            if self.lost.borrow().contains(host) {
                continue;
            }
            match self.command(host, &HostCommand::End) {
                Ok(reply) => {
                    links.insert(host.clone(), reply.link);
                }
                Err(e) => tracing::warn!("ending the run: {e:#}"),
            }
        }
        links
    }
}

/// The shortest wait for an answer to one join request.
const JOIN_ATTEMPT: Duration = Duration::from_millis(500);

/// Asks host `name`, listening at `endpoint`, to join the run as `request` says, for at
/// most `timeout`; its link once it has.
fn join_host(
    session: &zenoh::Session,
    name: &str,
    request: &JoinRequest,
    timeout: Duration,
    endpoint: String,
) -> anyhow::Result<HostLink> {
    let reply = ask_to_join(session, name, request, timeout).map_err(|e| {
        anyhow!(
            "host `{name}` at {endpoint} did not join the run: {e} (is `scmpc host \
             --name {name} --listen {endpoint}` running there?)"
        )
    })?;
    if !reply.error.is_empty() {
        return Err(anyhow!(
            "host `{name}` at {endpoint} refused the run: {}",
            reply.error
        ));
    }
    Ok(HostLink {
        endpoint,
        agent_pid: reply.agent_pid,
        prefix: reply.prefix,
        clock: reply.clock,
    })
}

/// Asks the agent of `host` to join, again and again until it answers or `timeout`
/// passes: a query fails at once while the link to the agent is not up yet.
fn ask_to_join(
    session: &zenoh::Session,
    host: &str,
    request: &JoinRequest,
    timeout: Duration,
) -> Result<JoinReply, hosts::HostError> {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match messages::ask(
            session,
            &keys::agent_join(host),
            request,
            left.max(JOIN_ATTEMPT),
        ) {
            Ok(reply) => return Ok(reply),
            Err(e) if Instant::now() >= deadline => {
                return Err(hosts::HostError::Protocol(format!(
                    "no answer within {timeout:?} (the last attempt: {e})"
                )));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}
