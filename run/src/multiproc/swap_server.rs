//! The server side of swap-in (the client is `scmpc swap`, `crate::swap_client`): the
//! scenario's scheduled swaps and live requests, a replacement started beside the process
//! it replaces, warmed up, switched in at a sample boundary, or stopped when it fails.

use super::session::Session;
use super::{STOP_TIMEOUT, SWAP_WARMUP_SAMPLES, SWITCH_LEAD_SAMPLES};
use crate::children::Children;
use protocol::{ControlCommand, Role, Scenario, SwapReply, Timing};
use record::{Event, Recorder};
use runtime::clock::RunMode;
use std::time::{Duration, Instant};

/// A replacement being swapped in (docs/design.md, "Supervision").
struct Swap {
    role: Role,
    /// Epoch of the replacement, and of the process it replaces.
    epoch: u32,
    replaces: u32,
    pid: u32,
    /// The command as shown in events.
    command: String,
    started: Instant,
    /// The `scmpc swap` request to answer, if it came from one.
    request: Option<Requester>,
    /// First and newest tick the replacement has published while warming up.
    heard: Option<(u64, u64)>,
    /// First tick taken from the replacement, once scheduled.
    switch_tick: Option<u64>,
}

/// A swap waiting for its time, or for its role to be free of another swap.
struct PendingSwap {
    time_s: f64,
    role: Role,
    command: Vec<String>,
    /// The `scmpc swap` request to answer.
    request: Option<Requester>,
}

/// Who asked for a live swap: the answer goes to this request of this client alone.
#[derive(Debug, Clone, Copy)]
struct Requester {
    request_id: u64,
    /// The iceoryx2 publisher the request came from.
    publisher: u128,
}

/// The swaps of a run: scheduled, asked for live, and under way.
pub(super) struct SwapServer {
    timing: Timing,
    /// `supervision.swap_timeout_s`: a replacement not warm this long after it was started
    /// is stopped, and the swap fails.
    timeout: Duration,
    /// The roles of the run (`scmpc swap` of another is refused).
    roles: Vec<Role>,
    /// Swaps not started yet, earliest first: the scenario's, and live requests (time 0).
    scheduled: Vec<PendingSwap>,
    swaps: Vec<Swap>,
    done: u32,
    /// Swaps that started and did not take over: `role epoch N (command): reason`.
    failed: Vec<String>,
}

/// The run's ports, processes and record: what the driver holds and the swap server works
/// with.
pub(super) struct Parts<'a> {
    pub session: &'a Session,
    pub children: &'a mut Children,
    pub recorder: &'a mut Recorder,
}

impl SwapServer {
    pub fn new(scenario: &Scenario) -> SwapServer {
        SwapServer {
            timing: scenario.timing.clone(),
            timeout: protocol::wait_of_s(scenario.supervision.swap_timeout_s),
            roles: scenario.roles().collect(),
            scheduled: scheduled_swaps(scenario),
            swaps: Vec::new(),
            done: 0,
            failed: Vec::new(),
        }
    }

    /// Swaps completed.
    pub fn done(&self) -> u32 {
        self.done
    }

    /// The swaps that started and did not take over, one line each.
    pub fn failed(&self) -> Vec<String> {
        self.failed.clone()
    }

    /// Whether a replacement under way has not joined the run yet (`joined`: whether the
    /// process of a role and epoch has reported ready).
    pub fn awaiting_join(&self, joined: impl Fn(Role, u32) -> bool) -> bool {
        self.swaps.iter().any(|s| !joined(s.role, s.epoch))
    }

    /// Starts swaps that are due by run time `time_s`, takes live requests, and moves
    /// every swap on: a warm replacement is scheduled to take over at a sample boundary
    /// [`SWITCH_LEAD_SAMPLES`] ahead of `now_tick`; once tick `recorded` is past its switch
    /// the old process is retired.
    pub fn serve(&mut self, p: &mut Parts, now_tick: u64, recorded: u64) -> anyhow::Result<()> {
        let time_s = self.timing.tick_time_s(recorded);
        self.take_requests(p)?;
        // One swap per role at a time: the next starts once the process replaced has exited.
        while let Some(i) = self.scheduled.iter().position(|s| {
            s.time_s <= time_s
                && self.swaps.iter().all(|w| w.role != s.role)
                && !p.children.retiring(s.role)
        }) {
            let s = self.scheduled.remove(i);
            self.begin(p, s.role, s.command, s.request)?;
        }
        let mut i = 0;
        while i < self.swaps.len() {
            let swap = &mut self.swaps[i];
            let role = swap.role;
            match swap.switch_tick {
                None => {
                    if let Some(t) = p
                        .session
                        .output_of(role)
                        .and_then(|i| i.take_standby_newest())
                    {
                        let (first, _) = swap.heard.unwrap_or((t, t));
                        swap.heard = Some((first, t));
                    }
                    let warmup_ticks = self.timing.first_tick(SWAP_WARMUP_SAMPLES);
                    let warm = swap
                        .heard
                        .is_some_and(|(first, newest)| newest >= first + warmup_ticks);
                    if warm {
                        let newest = swap.heard.map_or(0, |h| h.1);
                        let lead =
                            now_tick.max(newest) + self.timing.first_tick(SWITCH_LEAD_SAMPLES);
                        let tick = self.timing.next_sample_start(lead);
                        swap.switch_tick = Some(tick);
                        let epoch = swap.epoch;
                        p.session.reschedule(|s| s.schedule_switch(role, tick))?;
                        p.recorder.event(Event::SwapScheduled {
                            role,
                            epoch,
                            switch_tick: tick,
                        })?;
                    } else if swap.started.elapsed() > self.timeout {
                        let swap = self.swaps.remove(i);
                        self.fail(
                            p,
                            swap,
                            &format!(
                                "the replacement published nothing usable within {:?}",
                                self.timeout
                            ),
                        )?;
                        continue;
                    }
                }
                Some(tick) if recorded > tick => {
                    let swap = self.swaps.remove(i);
                    self.complete(p, swap, "switched")?;
                    continue;
                }
                Some(_) => {}
            }
            i += 1;
        }
        Ok(())
    }

    /// Takes the live requests of `scmpc swap` (straight from shared memory: nothing
    /// waits on this listener), each held to what a scheduled swap is.
    fn take_requests(&mut self, p: &mut Parts) -> anyhow::Result<()> {
        while let Some((r, _, publisher)) = p.session.swap_requests.receive_with_origin()? {
            let asker = Requester {
                request_id: r.request_id,
                publisher,
            };
            let command = r.command();
            // A live request is held to what a scheduled swap is.
            let checked = match Role::from_code(r.role) {
                Some(Role::Plant) => Err("the plant cannot be swapped".to_string()),
                Some(role) if !self.roles.contains(&role) => {
                    Err(format!("no {} runs in this run", role.as_str()))
                }
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
                    p.recorder.event(Event::SwapRefused {
                        role: Role::from_code(r.role),
                        command: command.join(" "),
                        reason: why.clone(),
                    })?;
                    reply(p.session, asker, None, &why)?;
                }
            }
        }
        Ok(())
    }
    /// Starts `command` (empty: the built-in process) as the replacement of `role`.
    fn begin(
        &mut self,
        p: &mut Parts,
        role: Role,
        command: Vec<String>,
        request: Option<Requester>,
    ) -> anyhow::Result<()> {
        let epoch = p.children.take_epoch();
        let replaces = p.session.schedule().current(role);
        p.session.reschedule(|s| s.announce(role, epoch))?;
        let _ = p
            .session
            .output_of(role)
            .and_then(|i| i.take_standby_newest());
        let shown = if command.is_empty() {
            format!("scmpc {}", role.as_str())
        } else {
            command.join(" ")
        };
        match p.children.spawn_role(role, epoch, &command) {
            Ok(pid) => {
                p.recorder.event(Event::SwapStarted {
                    role,
                    epoch,
                    replaces,
                    pid,
                    command: shown.clone(),
                    host: p.children.host_of(role).map(String::from),
                })?;
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
                p.session.reschedule(|s| s.unschedule(role))?;
                self.failed
                    .push(failure(role, epoch, &shown, &format!("{e:#}")));
                p.recorder.event(Event::SwapFailed {
                    role,
                    epoch,
                    command: shown,
                    reason: format!("{e:#}"),
                })?;
                match request {
                    Some(id) => reply(p.session, id, None, &format!("{e:#}")),
                    None => Ok(()),
                }
            }
        }
    }

    /// The process of `role` and `epoch` exited: if it was a replacement warming up, its
    /// swap fails (returns true).
    pub fn replacement_exited(
        &mut self,
        p: &mut Parts,
        role: Role,
        epoch: u32,
        status: &str,
    ) -> anyhow::Result<bool> {
        let Some(i) = self
            .swaps
            .iter()
            .position(|s| s.role == role && s.epoch == epoch)
        else {
            return Ok(false);
        };
        let swap = self.swaps.remove(i);
        self.fail(p, swap, &format!("the replacement exited ({status})"))?;
        Ok(true)
    }

    /// The active process of `role` crashed: its replacement, if one is running, takes
    /// over at once (returns true).
    pub fn promote(&mut self, p: &mut Parts, role: Role) -> anyhow::Result<bool> {
        let Some(i) = self.swaps.iter().position(|s| s.role == role) else {
            return Ok(false);
        };
        let swap = self.swaps.remove(i);
        self.complete(p, swap, "promoted after the crash")?;
        Ok(true)
    }

    /// The run has ended: every swap that did not happen is answered.
    pub fn finish(&mut self, p: &mut Parts) -> anyhow::Result<()> {
        for swap in std::mem::take(&mut self.swaps) {
            self.fail(p, swap, "the run ended before the switch")?;
        }
        for pending in std::mem::take(&mut self.scheduled) {
            if let Some(asker) = pending.request {
                reply(
                    p.session,
                    asker,
                    None,
                    "the run ended before the swap could start",
                )?;
            }
        }
        Ok(())
    }

    /// The replacement has taken over (at its switch tick, or at once when the process it
    /// replaces died): the old process is retired.
    fn complete(&mut self, p: &mut Parts, swap: Swap, how: &str) -> anyhow::Result<()> {
        let role = swap.role;
        let old_pid = p.children.pid(role, swap.replaces);
        if old_pid.is_some() {
            p.children.retire(role, swap.replaces, STOP_TIMEOUT);
        } else {
            p.session.reschedule(|s| s.activate(role, swap.epoch))?;
            if p.session.clock().mode() == RunMode::Lockstep {
                // The loop may be waiting for a sample only the new producer can now give.
                p.session.command(ControlCommand::Replay)?;
            }
        }
        self.done += 1;
        p.recorder.event(Event::Swapped {
            role,
            from_epoch: swap.replaces,
            to_epoch: swap.epoch,
            old_pid,
            new_pid: swap.pid,
            switch_tick: swap.switch_tick,
            how: how.to_string(),
            warmup_s: swap.started.elapsed().as_secs_f64(),
        })?;
        match swap.request {
            Some(id) => reply(p.session, id, Some(&swap), how),
            None => Ok(()),
        }
    }
}

impl SwapServer {
    /// Drops a replacement: the old process stays the producer; the replacement is retired if
    /// it still runs.
    fn fail(&mut self, p: &mut Parts, swap: Swap, reason: &str) -> anyhow::Result<()> {
        let role = swap.role;
        self.failed
            .push(failure(role, swap.epoch, &swap.command, reason));
        p.session.reschedule(|s| s.unschedule(role))?;
        p.children.retire(role, swap.epoch, STOP_TIMEOUT);
        if p.session.clock().mode() == RunMode::Lockstep && swap.switch_tick.is_some() {
            // Samples of the old producer past the switch were skipped: have them again.
            p.session.command(ControlCommand::Replay)?;
        }
        p.recorder.event(Event::SwapFailed {
            role,
            epoch: swap.epoch,
            command: swap.command.clone(),
            reason: reason.to_string(),
        })?;
        match swap.request {
            Some(id) => reply(p.session, id, None, reason),
            None => Ok(()),
        }
    }
}

/// A failed swap's line of the end table.
fn failure(role: Role, epoch: u32, command: &str, reason: &str) -> String {
    format!("{} epoch {epoch} (`{command}`): {reason}", role.as_str())
}

/// Answers a `scmpc swap` request: done with `swap`, or failed.
fn reply(
    session: &Session,
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
    Ok(session.swap_replies.send(reply)?)
}

/// The scenario's `[[swap]]` entries, earliest first (validated: the roles are swappable).
fn scheduled_swaps(scenario: &Scenario) -> Vec<PendingSwap> {
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
