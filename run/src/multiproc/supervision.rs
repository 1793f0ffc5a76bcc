//! Supervision: the processes' status reports (refused samples, processes that joined),
//! producers that fail the border checks, the scan for dead iceoryx2 nodes, and restarts.

use super::session::Session;
use super::{NODE_LISTING, NODE_SCAN};
use crate::children::Children;
use protocol::{ControlCommand, Rejection, RestartPolicy, Role, Status, StatusEvent, Supervision};
use record::Recorder;
use record::event::{Event, NewProcess, Ready, Restart};
use runtime::ipc;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};

/// How long a producer's own samples may be refused, none taken, before it is treated as
/// failed ([`Supervisor::contain`]).
pub(super) const REFUSED_LIMIT: Duration = Duration::from_millis(500);

/// Samples of a producer refused through its own fault, since `since`.
#[derive(Debug, Clone, Copy)]
struct Blame {
    since: Instant,
    epoch: u32,
    /// Samples of the role the orchestrator had taken at `since`.
    taken: u64,
}

/// What supervision keeps across the run.
pub(super) struct Supervisor {
    policy: Supervision,
    restarts: u32,
    /// Samples refused by any consumer, by reason.
    rejected: BTreeMap<String, u64>,
    /// Per role: since when its own samples have been refused.
    blamed: [Option<Blame>; Role::COUNT],
    last_node_scan: Instant,
    /// `None`: list at the next scan (a process has just joined).
    last_node_listing: Option<Instant>,
    /// Processes of the run's living nodes, as last listed.
    node_pids: Vec<u32>,
    /// The processes (role, epoch) that have reported ready since the run started.
    joined: Vec<(Role, u32)>,
    /// What the plant takes, when a lost input of it is worth naming, by the index its
    /// status gives (a ROS 2 robot's odometry key, and its scans' with a lidar).
    plant_inputs: Vec<String>,
}

impl Supervisor {
    pub fn new(policy: &Supervision, plant_inputs: Vec<String>) -> Supervisor {
        Supervisor {
            policy: policy.clone(),
            plant_inputs,
            restarts: 0,
            rejected: BTreeMap::new(),
            blamed: [None; Role::COUNT],
            last_node_scan: Instant::now(),
            last_node_listing: None,
            node_pids: Vec::new(),
            joined: Vec::new(),
        }
    }

    /// Whether the process of `role` and `epoch` has reported ready since the run started.
    pub fn has_joined(&self, role: Role, epoch: u32) -> bool {
        self.joined.contains(&(role, epoch))
    }

    /// Restarts so far.
    pub fn restarts(&self) -> u32 {
        self.restarts
    }

    /// Samples refused so far, by reason.
    pub fn take_rejected(&mut self) -> BTreeMap<String, u64> {
        std::mem::take(&mut self.rejected)
    }

    /// Takes the processes' status reports: refused samples (the orchestrator's own
    /// included) are counted and recorded by reason, and a process that joined the running
    /// loop is told the clock and the schedule, and every producer repeats its newest
    /// sample for it.
    pub fn take_status(
        &mut self,
        session: &Session,
        children: &Children,
        recorder: &mut Recorder,
    ) -> anyhow::Result<()> {
        let mut joined = Vec::new();
        let mut rejected = Vec::new();
        let mut lost = Vec::new();
        session.status.drain(|s, _| {
            if let Some(ready) = ready_role(&s) {
                joined.push(ready);
            } else if s.event == StatusEvent::InputLost as u32 {
                lost.extend(Role::from_code(s.role).map(|role| (role, s.detail)));
            } else if s.event == StatusEvent::Rejected as u32 {
                rejected.push((
                    Role::from_code(s.role).map_or("unknown", Role::as_str),
                    Role::from_code(s.producer),
                    s.detail,
                    s.count,
                ));
            }
        })?;
        for (producer, code, count) in session.take_rejections() {
            rejected.push(("orchestrator", producer, code, count));
        }
        for (consumer, producer, code, count) in rejected {
            let reason = Rejection::ALL.get(code as usize);
            if let (Some(role), true) = (producer, reason.is_some_and(|r| r.blames_producer())) {
                self.blame(session, role);
            }
            let reason = reason.map_or("unknown", |r| r.as_str());
            *self.rejected.entry(reason.to_string()).or_default() += count;
            recorder.event(Event::Rejected {
                consumer: consumer.to_string(),
                reason: reason.to_string(),
                count,
            })?;
        }
        for (role, index) in lost {
            let input = (role == Role::Plant)
                .then(|| self.plant_inputs.get(index as usize).cloned())
                .flatten();
            recorder.event(Event::InputLost { role, input })?;
        }
        for (role, s) in joined {
            let epoch = s.header.epoch;
            self.joined.push((role, epoch));
            session.pin(role, epoch, children.pins(role, epoch, s.publishers))?;
            recorder.event(Event::Ready(Ready::Role { role }))?;
            self.last_node_listing = None;
            session.tell_the_clock()?;
            session.command(ControlCommand::Replay)?;
        }
        Ok(())
    }

    /// Notes that samples of the current producer of `role` were refused through its own
    /// fault ([`Rejection::blames_producer`]).
    fn blame(&mut self, session: &Session, role: Role) {
        let epoch = session.schedule().current(role);
        let slot = &mut self.blamed[role as usize];
        if slot.is_none_or(|b| b.epoch != epoch) {
            *slot = Some(Blame {
                since: Instant::now(),
                epoch,
                taken: session.output_of(role).map_or(0, |i| i.taken()),
            });
        }
    }

    /// A producer whose samples have been refused for [`REFUSED_LIMIT`] with none taken
    /// meanwhile has failed: it is recorded (`refused_too_long`) and killed, and its exit
    /// is handled as a crash (restart or abort, by the scenario's policy). Meanwhile its
    /// consumers fall back as for a silent producer (the DFL flies the committed plan,
    /// then brakes).
    pub fn contain(
        &mut self,
        session: &Session,
        children: &mut Children,
        recorder: &mut Recorder,
    ) -> anyhow::Result<()> {
        for role in Role::ALL {
            let Some(blame) = self.blamed[role as usize] else {
                continue;
            };
            let recovered = session.output_of(role).map_or(0, |i| i.taken()) > blame.taken;
            let replaced = session.schedule().current(role) != blame.epoch;
            if recovered || replaced {
                self.blamed[role as usize] = None;
            } else if blame.since.elapsed() >= REFUSED_LIMIT {
                self.blamed[role as usize] = None;
                let pid = children.kill_running(role, blame.epoch);
                recorder.event(Event::RefusedTooLong {
                    role,
                    epoch: blame.epoch,
                    pid,
                    limit_s: REFUSED_LIMIT.as_secs_f64(),
                })?;
            }
        }
        Ok(())
    }

    /// Looks for dead nodes every [`NODE_SCAN`]: a full iceoryx2 node listing (about 1 ms
    /// of CPU) every [`NODE_LISTING`], and in between only whether the processes of the
    /// nodes listed are still alive (microseconds), so the scan does not disturb the
    /// control loop.
    pub fn watch_nodes(
        &mut self,
        children: &mut Children,
        recorder: &mut Recorder,
    ) -> anyhow::Result<()> {
        if self.last_node_scan.elapsed() < NODE_SCAN {
            return Ok(());
        }
        self.last_node_scan = Instant::now();
        let someone_died = self.node_pids.iter().any(|pid| !ipc::process_alive(*pid));
        if someone_died
            || self
                .last_node_listing
                .is_none_or(|t| t.elapsed() >= NODE_LISTING)
        {
            let scan =
                ipc::scan_nodes_of(&children.prefix, ours(children.robot())).unwrap_or_default();
            record_dead_nodes(&scan.cleaned, children, recorder, None)?;
            self.node_pids = scan.alive_pids;
            self.last_node_listing = Some(Instant::now());
        }
        Ok(())
    }

    /// The host of a process of `role` is gone: with `supervision.failover = "local"` a
    /// replacement starts on this host with a new epoch and takes over at once (its host
    /// is lost, so nothing of the old one is left to break); returns false otherwise (the
    /// run ends aborted).
    pub fn fail_over(
        &mut self,
        role: Role,
        session: &Session,
        children: &mut Children,
        recorder: &mut Recorder,
    ) -> anyhow::Result<bool> {
        if self.policy.failover != protocol::Failover::Local {
            return Ok(false);
        }
        start_new_epoch(role, Event::FailedOver, session, children, recorder)?;
        Ok(true)
    }

    /// A crashed process of `role`: restarted per the scenario's policy with a new epoch
    /// (returns false when the policy allows none: the run ends aborted; a dead plant
    /// always ends it).
    pub fn restart(
        &mut self,
        role: Role,
        session: &Session,
        children: &mut Children,
        recorder: &mut Recorder,
    ) -> anyhow::Result<bool> {
        let restartable = role != Role::Plant
            && self.policy.restart == RestartPolicy::Always
            && self.restarts < self.policy.max_restarts;
        if !restartable {
            return Ok(false);
        }
        self.restarts += 1;
        start_new_epoch(
            role,
            |p| Event::Restarted(Restart::Process(p)),
            session,
            children,
            recorder,
        )?;
        Ok(true)
    }
}

/// Starts the built-in process of `role` with a new epoch, made active at once, and
/// records `event` for it.
fn start_new_epoch(
    role: Role,
    event: fn(NewProcess) -> Event,
    session: &Session,
    children: &mut Children,
    recorder: &mut Recorder,
) -> anyhow::Result<()> {
    let epoch = children.take_epoch();
    session.reschedule(|s| s.activate(role, epoch))?;
    let pid = children.spawn_role(role, epoch, &[])?;
    recorder.event(event(NewProcess {
        role,
        pid,
        epoch,
        host: children.host_of(role).map(String::from),
    }))?;
    Ok(())
}

/// iceoryx2's dead-node detection: removes what dead nodes of the run left. A role
/// process that died while the process the orchestrator started for it lives on (a
/// wrapper script, say) is recorded as `dead_node`, and that process is killed, so its
/// exit is handled as a crash. Nothing is recorded for the node of `exited` (the child
/// whose exit is being handled) nor for one whose child has exited already (its exit
/// comes next). Returns how many nodes were cleaned.
pub(super) fn clean_dead_nodes(
    children: &mut Children,
    recorder: &mut Recorder,
    exited: Option<(Role, u32)>,
) -> anyhow::Result<usize> {
    let names =
        ipc::cleanup_dead_nodes_of(&children.prefix, ours(children.robot())).unwrap_or_default();
    record_dead_nodes(&names, children, recorder, exited)?;
    Ok(names.len())
}

/// Records the dead nodes `names` of [`clean_dead_nodes`] and kills their processes.
fn record_dead_nodes(
    names: &[String],
    children: &mut Children,
    recorder: &mut Recorder,
    exited: Option<(Role, u32)>,
) -> anyhow::Result<()> {
    for name in names {
        let Some((_, role, epoch)) = ipc::role_of_node(name) else {
            continue;
        };
        if exited == Some((role, epoch)) {
            continue;
        }
        let ours = children.pid(role, epoch).is_some();
        let killed = children.kill_running(role, epoch);
        if killed.is_some() || !ours {
            recorder.event(Event::DeadNode {
                node: name.to_string(),
                role,
                epoch,
                child_killed: killed,
            })?;
        }
    }
    Ok(())
}

/// Whether a node of the run is robot `robot`'s: in a fleet each robot's supervisor
/// watches and cleans its own robot's nodes (the first robot's those of no role too), so
/// that each sees the deaths of its own, and a fleet of eight does not look at every
/// process eight times (`swap8`'s orchestrator read `/proc` for 16 % of its time).
fn ours(robot: u32) -> impl Fn(&str) -> bool {
    move |name| {
        ipc::role_of_node(name).map_or(robot == protocol::FIRST_ROBOT, |(r, _, _)| r == robot)
    }
}

/// The role of a ready report.
pub(super) fn ready_role(s: &Status) -> Option<(Role, Status)> {
    (s.event == StatusEvent::Ready as u32)
        .then(|| Role::from_code(s.role))
        .flatten()
        .map(|role| (role, *s))
}
