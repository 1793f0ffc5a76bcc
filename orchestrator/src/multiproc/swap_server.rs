//! The server side of swap-in (the client is `scmpc swap`, `crate::swap_client`): the
//! scenario's scheduled swaps and live requests, a replacement started beside the process
//! it replaces, warmed up, switched in at a sample boundary, or stopped when it fails.

use super::*;

/// A replacement being swapped in (README, "Supervision").
pub(super) struct Swap {
    pub(super) role: Role,
    /// Epoch of the replacement, and of the process it replaces.
    pub(super) epoch: u32,
    pub(super) replaces: u32,
    pub(super) pid: u32,
    /// The command as shown in events.
    pub(super) command: String,
    pub(super) started: Instant,
    /// The `scmpc swap` request to answer, if it came from one.
    pub(super) request: Option<Requester>,
    /// First and newest tick the replacement has published while warming up.
    pub(super) heard: Option<(u64, u64)>,
    /// First tick taken from the replacement, once scheduled.
    pub(super) switch_tick: Option<u64>,
}

/// A swap waiting for its time, or for its role to be free of another swap.
pub(super) struct PendingSwap {
    pub(super) time_s: f64,
    pub(super) role: Role,
    pub(super) command: Vec<String>,
    /// The `scmpc swap` request to answer.
    pub(super) request: Option<Requester>,
}

/// Who asked for a live swap: the answer goes to this request of this client alone.
#[derive(Debug, Clone, Copy)]
pub(super) struct Requester {
    pub(super) request_id: u64,
    /// The iceoryx2 publisher the request came from.
    pub(super) publisher: u128,
}

impl Driver<'_> {
    /// Starts swaps that are due, takes live requests, and moves every swap on: a warm
    /// replacement is scheduled to take over at a sample boundary [`SWITCH_LEAD_SAMPLES`]
    /// ahead; once that tick is recorded the old process is retired.
    pub(super) fn supervise(&mut self) -> anyhow::Result<()> {
        self.show_status();
        let time_s = self.cursor as f64 * self.scenario.timing.dt_s();
        // Straight from shared memory: nothing waits on this listener.
        while let Some((r, _, publisher)) = self.session.swap_requests.receive_with_origin()? {
            let asker = Requester {
                request_id: r.request_id,
                publisher,
            };
            let command = r.command();
            // A live request is held to what a scheduled swap is.
            let checked = match Role::from_code(r.role) {
                Some(Role::Plant) => Err("the plant cannot be swapped".to_string()),
                Some(role) if !self.scenario.roles().any(|r| r == role) => Err(format!(
                    "no {} runs in this run (planner.kind = \"none\")",
                    role.as_str()
                )),
                Some(role) => crate::scenarios::check_swap_command(&command).map(|()| role),
                None => Err(format!("no role with code {}", r.role)),
            };
            match checked {
                Ok(role) => self.scheduled.push(PendingSwap {
                    time_s: 0.0,
                    role,
                    command,
                    request: Some(asker),
                }),
                Err(why) => {
                    self.recorder.event(
                        "swap_refused",
                        serde_json::json!({ "role": Role::from_code(r.role).map(Role::as_str), "command": command.join(" "), "reason": why }),
                    )?;
                    self.reply(asker, None, &why)?;
                }
            }
        }
        // One swap per role at a time: the next starts once the process replaced has exited.
        while let Some(i) = self.scheduled.iter().position(|p| {
            p.time_s <= time_s
                && self.swaps.iter().all(|s| s.role != p.role)
                && !self.children.retiring(p.role)
        }) {
            let p = self.scheduled.remove(i);
            self.begin_swap(p.role, p.command, p.request)?;
        }
        let inner_steps = self.scenario.timing.inner_steps as u64;
        let now_tick = self.now_tick();
        let mut i = 0;
        while i < self.swaps.len() {
            let swap = &mut self.swaps[i];
            let role = swap.role;
            match swap.switch_tick {
                None => {
                    if let Some(t) = self.session.output_of(role).take_standby_newest() {
                        let (first, _) = swap.heard.unwrap_or((t, t));
                        swap.heard = Some((first, t));
                    }
                    let warm = swap.heard.is_some_and(|(first, newest)| {
                        newest >= first + SWAP_WARMUP_SAMPLES * inner_steps
                    });
                    if warm {
                        let newest = swap.heard.map_or(0, |h| h.1);
                        let lead = now_tick.max(newest) + SWITCH_LEAD_SAMPLES * inner_steps;
                        let tick = lead.div_ceil(inner_steps) * inner_steps;
                        swap.switch_tick = Some(tick);
                        let epoch = swap.epoch;
                        self.session.reschedule(|s| s.schedule_switch(role, tick))?;
                        self.recorder.event(
                            "swap_scheduled",
                            serde_json::json!({ "role": role.as_str(), "epoch": epoch, "switch_tick": tick }),
                        )?;
                    } else if swap.started.elapsed() > SWAP_TIMEOUT {
                        let swap = self.swaps.remove(i);
                        self.fail_swap(
                            swap,
                            &format!(
                                "the replacement published nothing usable within {SWAP_TIMEOUT:?}"
                            ),
                        )?;
                        continue;
                    }
                }
                Some(tick) if self.cursor > tick => {
                    let swap = self.swaps.remove(i);
                    self.complete_swap(swap, "switched")?;
                    continue;
                }
                Some(_) => {}
            }
            i += 1;
        }
        Ok(())
    }

    /// Starts `command` (empty: the built-in process) as the replacement of `role`.
    pub(super) fn begin_swap(
        &mut self,
        role: Role,
        command: Vec<String>,
        request: Option<Requester>,
    ) -> anyhow::Result<()> {
        let epoch = self.take_epoch();
        let replaces = self.session.schedule.get().current(role);
        self.session.reschedule(|s| s.announce(role, epoch))?;
        let _ = self.session.output_of(role).take_standby_newest();
        let shown = if command.is_empty() {
            format!("scmpc {}", role.as_str())
        } else {
            command.join(" ")
        };
        match self.children.spawn_role(role, epoch, &command) {
            Ok(pid) => {
                self.recorder.event(
                    "swap_started",
                    serde_json::json!({ "role": role.as_str(), "epoch": epoch, "replaces": replaces, "pid": pid, "command": shown }),
                )?;
                self.swaps.push(Swap {
                    role,
                    epoch,
                    replaces,
                    pid,
                    command: shown,
                    started: Instant::now(),
                    request,
                    heard: None,
                    switch_tick: None,
                });
                Ok(())
            }
            Err(e) => {
                self.session.reschedule(|s| s.unschedule(role))?;
                self.recorder.event(
                    "swap_failed",
                    serde_json::json!({ "role": role.as_str(), "epoch": epoch, "command": shown, "reason": format!("{e:#}") }),
                )?;
                match request {
                    Some(id) => self.reply(id, None, &format!("{e:#}")),
                    None => Ok(()),
                }
            }
        }
    }

    /// The replacement has taken over (at its switch tick, or at once when the process it
    /// replaces died): the old process is retired.
    pub(super) fn complete_swap(&mut self, swap: Swap, how: &str) -> anyhow::Result<()> {
        let role = swap.role;
        let old_pid = self.children.pid(role, swap.replaces);
        if old_pid.is_some() {
            self.children.retire(role, swap.replaces, STOP_TIMEOUT);
        } else {
            self.session.reschedule(|s| s.activate(role, swap.epoch))?;
            if self.mode == RunMode::Lockstep {
                // The loop may be waiting for a sample only the new producer can now give.
                self.session.command(ControlCommand::Replay, 0, 0)?;
            }
        }
        self.swaps_done += 1;
        let tick = swap.switch_tick;
        self.recorder.event(
            "swapped",
            serde_json::json!({
                "role": role.as_str(), "from_epoch": swap.replaces, "to_epoch": swap.epoch,
                "old_pid": old_pid, "new_pid": swap.pid, "switch_tick": tick, "how": how,
                "warmup_s": swap.started.elapsed().as_secs_f64(),
            }),
        )?;
        match swap.request {
            Some(id) => self.reply(id, Some(&swap), how),
            None => Ok(()),
        }
    }

    /// Drops a replacement: the old process stays the producer; the replacement is
    /// retired if it still runs.
    pub(super) fn fail_swap(&mut self, swap: Swap, reason: &str) -> anyhow::Result<()> {
        let role = swap.role;
        self.session.reschedule(|s| s.unschedule(role))?;
        self.children.retire(role, swap.epoch, STOP_TIMEOUT);
        if self.mode == RunMode::Lockstep && swap.switch_tick.is_some() {
            // Samples of the old producer past the switch were skipped: have them again.
            self.session.command(ControlCommand::Replay, 0, 0)?;
        }
        self.recorder.event(
            "swap_failed",
            serde_json::json!({ "role": role.as_str(), "epoch": swap.epoch, "command": swap.command, "reason": reason }),
        )?;
        match swap.request {
            Some(id) => self.reply(id, None, reason),
            None => Ok(()),
        }
    }

    /// Answers a `scmpc swap` request: done with `swap`, or failed.
    pub(super) fn reply(
        &self,
        to: Requester,
        swap: Option<&Swap>,
        message: &str,
    ) -> anyhow::Result<()> {
        let reply = SwapReply {
            request_id: to.request_id,
            requester: to.publisher,
            done: u32::from(swap.is_some()),
            epoch: swap.map_or(0, |s| s.epoch),
            switch_tick: swap.and_then(|s| s.switch_tick).unwrap_or(0),
            ..SwapReply::default()
        }
        .with_message(message);
        Ok(self.session.swap_replies.send(reply)?)
    }
}

/// The scenario's `[[swap]]` entries, earliest first (validated: the roles are swappable).
pub(super) fn scheduled_swaps(scenario: &Scenario) -> Vec<PendingSwap> {
    let mut swaps: Vec<_> = scenario
        .swap
        .iter()
        .filter_map(|s| {
            Some(PendingSwap {
                time_s: s.time_s,
                role: s.swappable_role()?,
                command: s.command.clone(),
                request: None,
            })
        })
        .collect();
    swaps.sort_by(|a, b| a.time_s.total_cmp(&b.time_s));
    swaps
}
