//! Supervision: a process that exited (retired, a failed replacement, or a crash that is
//! restarted or aborts the run), and the scan for dead iceoryx2 nodes.

use super::*;

impl Driver<'_> {
    /// Ends the run on Ctrl-C; handles a process that exited: a retired one is
    /// forgotten, a failed replacement cancels its swap, and a dead active process is
    /// cleaned up after and then replaced by its warming replacement if there is one, else
    /// restarted per the scenario's supervision policy, else the run ends as aborted.
    pub(super) fn check(&mut self) -> anyhow::Result<Option<Outcome>> {
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        self.children.kill_overdue();
        self.contain()?;
        if self.last_node_scan.elapsed() >= NODE_SCAN {
            self.last_node_scan = Instant::now();
            self.watch_nodes()?;
        }
        let Some((proc, status)) = self.children.take_exited() else {
            return Ok(None);
        };
        let role = proc.role;
        let cleaned = self.clean_dead_nodes(Some((role, proc.epoch)))?;
        if proc.retire_by.is_some() {
            self.recorder.event(
                "retired",
                serde_json::json!({ "role": role.as_str(), "epoch": proc.epoch, "status": status.to_string() }),
            )?;
            return Ok(None);
        }
        if let Some(i) = self
            .swaps
            .iter()
            .position(|s| s.role == role && s.epoch == proc.epoch)
        {
            let swap = self.swaps.remove(i);
            self.fail_swap(swap, &format!("the replacement exited ({status})"))?;
            return Ok(None);
        }
        // A terminal's Ctrl-C reaches the whole process group: the children may see it a
        // moment before the orchestrator's handler runs.
        std::thread::sleep(Duration::from_millis(20));
        if self.stop.load(Ordering::Relaxed) {
            return Ok(Some(Outcome::Interrupted));
        }
        self.recorder.event(
            "crashed",
            serde_json::json!({ "role": role.as_str(), "epoch": proc.epoch, "status": status.to_string(), "nodes_cleaned": cleaned }),
        )?;
        if let Some(i) = self.swaps.iter().position(|s| s.role == role) {
            // Its replacement is already running: it takes over at once.
            let swap = self.swaps.remove(i);
            self.complete_swap(swap, "promoted after the crash")?;
            return Ok(None);
        }
        let policy = &self.scenario.supervision;
        let restartable = role != Role::Plant
            && policy.restart == RestartPolicy::Always
            && self.restarts < policy.max_restarts;
        if !restartable {
            return Ok(Some(Outcome::Aborted));
        }
        self.restarts += 1;
        let epoch = self.take_epoch();
        self.session.reschedule(|s| s.activate(role, epoch))?;
        let pid = self.children.spawn_role(role, epoch, &[])?;
        self.recorder.event(
            "restarted",
            serde_json::json!({ "role": role.as_str(), "pid": pid, "epoch": epoch }),
        )?;
        Ok(None)
    }

    /// Looks for dead nodes: a full iceoryx2 node listing (about 1 ms of CPU) every
    /// [`NODE_LISTING`], and in between only whether the processes of the nodes listed
    /// are still alive (microseconds), so the scan does not disturb the control loop.
    pub(super) fn watch_nodes(&mut self) -> anyhow::Result<()> {
        let someone_died = self.node_pids.iter().any(|pid| !ipc::process_alive(*pid));
        if someone_died
            || self
                .last_node_listing
                .is_none_or(|t| t.elapsed() >= NODE_LISTING)
        {
            self.clean_dead_nodes(None)?;
            self.node_pids = ipc::node_pids(&self.children.prefix).unwrap_or_default();
            self.last_node_listing = Some(Instant::now());
        }
        Ok(())
    }

    /// iceoryx2's dead-node detection: removes what dead nodes of the run left. A role
    /// process that died while the process the orchestrator started for it lives on (a
    /// wrapper script, say) is recorded as `dead_node`, and that process is killed, so its
    /// exit is handled as a crash. Nothing is recorded for the node of `exited` (the child
    /// whose exit is being handled) nor for one whose child has exited already (its exit
    /// comes next). Returns how many nodes were cleaned.
    pub(super) fn clean_dead_nodes(
        &mut self,
        exited: Option<(Role, u32)>,
    ) -> anyhow::Result<usize> {
        let names = ipc::cleanup_dead_nodes(&self.children.prefix).unwrap_or_default();
        for name in &names {
            let Some((role, epoch)) = ipc::role_of_node(name) else {
                continue;
            };
            if exited == Some((role, epoch)) {
                continue;
            }
            let ours = self.children.pid(role, epoch).is_some();
            let killed = self.children.kill_running(role, epoch);
            if killed.is_some() || !ours {
                self.recorder.event(
                    "dead_node",
                    serde_json::json!({ "node": name, "role": role.as_str(), "epoch": epoch, "child_killed": killed }),
                )?;
            }
        }
        Ok(names.len())
    }

    pub(super) fn take_epoch(&mut self) -> u32 {
        self.next_epoch += 1;
        self.next_epoch
    }

    /// Notes that samples of the current producer of `role` were refused through its own
    /// fault ([`Rejection::blames_producer`]).
    pub(super) fn blame(&mut self, role: Role) {
        let epoch = self.session.schedule.get().current(role);
        let slot = &mut self.blamed[role as usize];
        if slot.is_none_or(|b| b.epoch != epoch) {
            *slot = Some(Blame {
                since: Instant::now(),
                epoch,
                taken: self.session.output_of(role).taken(),
            });
        }
    }

    /// A producer whose samples have been refused for [`REFUSED_LIMIT`] with none taken
    /// meanwhile has failed: it is recorded (`refused_too_long`) and killed, and its exit
    /// is handled as a crash (restart or abort, by the scenario's policy). Meanwhile its
    /// consumers fall back as for a silent producer (the DFL flies the committed plan,
    /// then brakes).
    fn contain(&mut self) -> anyhow::Result<()> {
        for role in Role::ALL {
            let Some(blame) = self.blamed[role as usize] else {
                continue;
            };
            let recovered = self.session.output_of(role).taken() > blame.taken;
            let replaced = self.session.schedule.get().current(role) != blame.epoch;
            if recovered || replaced {
                self.blamed[role as usize] = None;
            } else if blame.since.elapsed() >= REFUSED_LIMIT {
                self.blamed[role as usize] = None;
                let pid = self.children.kill_running(role, blame.epoch);
                self.recorder.event(
                    "refused_too_long",
                    serde_json::json!({ "role": role.as_str(), "epoch": blame.epoch, "pid": pid, "limit_s": REFUSED_LIMIT.as_secs_f64() }),
                )?;
            }
        }
        Ok(())
    }
}

/// How long a producer's own samples may be refused, none taken, before it is treated as
/// failed ([`Driver::contain`]).
pub(super) const REFUSED_LIMIT: Duration = Duration::from_millis(500);

/// Samples of a producer refused through its own fault, since `since`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Blame {
    since: Instant,
    epoch: u32,
    /// Samples of the role the orchestrator had taken at `since`.
    taken: u64,
}
