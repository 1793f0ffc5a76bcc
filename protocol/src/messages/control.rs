//! The control plane's messages: what the orchestrator tells every process ([`Control`],
//! with the [`EpochSchedule`]), what a process reports ([`Status`], [`Rejection`]), and the
//! live swap request and its reply.

use super::Header;
pub use crate::graph::Role;
#[cfg(feature = "iceoryx2")]
use iceoryx2::prelude::ZeroCopySend;

/// What the orchestrator tells every process.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ControlCommand {
    /// Lockstep: the plant may publish tick `header.tick`.
    Grant = 0,
    /// Real time: tick 0 is at monotonic time `start_ns`.
    Start = 1,
    /// The run is over: exit cleanly.
    Stop = 2,
    /// Only the epoch schedule changed (a process was restarted or is being swapped).
    Epochs = 3,
    /// Every producer publishes its newest sample of each output again, so a process that
    /// joined a running loop (a restart, a replacement) gets what it missed; consumers
    /// skip ticks they have already handled.
    Replay = 4,
    /// A new goal (`goal*`; every control message carries the newest).
    Goal = 5,
}

/// The orchestrator's clock and commands.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::Control")
)]
pub struct Control {
    pub header: Header,
    /// [`ControlCommand`] code.
    pub command: u32,
    pub reserved: u32,
    /// Monotonic time of tick 0 (real time), ns.
    pub start_ns: u64,
    /// Which producer of each role consumers take, tick by tick.
    pub epochs: EpochSchedule,
    /// The newest goal set while the run drives (`goal_serial` 0: none, `robot.goal`):
    /// `[x, y, heading]` (m, m, rad; heading NaN: none), in force from `goal_from_tick`;
    /// and the one set before it, `prior_goal*` ([`crate::task::Goals`]).
    pub goal: [f64; 3],
    pub goal_from_tick: u64,
    pub goal_serial: u32,
    pub prior_goal_serial: u32,
    pub prior_goal: [f64; 3],
    pub prior_goal_from_tick: u64,
    pub reserved_goal: [u32; 2],
}

/// Which producer epoch of each [`Role`] (indexed by its code) consumers take, tick by
/// tick (docs/design.md, "Supervision"). A swap-in replacement is announced as `next` while it warms
/// up: its samples are neither used nor counted as rejected. Once `switch_tick` is set,
/// samples of ticks before it are taken from `active` and from it on from `next`, so the
/// hand-over happens at one sample boundary in every process alike. The schedule stays so
/// after the swap: the old producer's late samples are skipped, not rejected.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::EpochSchedule")
)]
pub struct EpochSchedule {
    pub active: [u32; Role::COUNT],
    /// The replacement being started, or the same as `active` when there is none.
    pub next: [u32; Role::COUNT],
    /// First tick taken from `next`; [`SWITCH_UNSCHEDULED`] while it warms up.
    pub switch_tick: [u64; Role::COUNT],
    /// The iceoryx2 publisher of each output of `active` (by role, then by the output's
    /// slot, [`output_slot`](crate::topics::output_slot)), as the process announced it when it
    /// joined; 0 while not known. A sample from another publisher is refused.
    pub active_publishers: [[u128; 2]; Role::COUNT],
    /// The same for `next`.
    pub next_publishers: [[u128; 2]; Role::COUNT],
}

/// `switch_tick` of a replacement that is still warming up.
pub const SWITCH_UNSCHEDULED: u64 = u64::MAX;

/// What a consumer does with a sample of a given producer epoch and tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EpochVerdict {
    Take,
    /// From a producer being swapped in (before its switch) or out (after it): not used,
    /// not an error.
    Standby,
    Reject,
}

impl Default for EpochSchedule {
    /// Epoch 0 of every role, no replacement.
    fn default() -> Self {
        EpochSchedule {
            active: [0; Role::COUNT],
            next: [0; Role::COUNT],
            switch_tick: [SWITCH_UNSCHEDULED; Role::COUNT],
            active_publishers: [[0; 2]; Role::COUNT],
            next_publishers: [[0; 2]; Role::COUNT],
        }
    }
}

impl EpochSchedule {
    /// The producer epoch whose samples of `tick` are taken.
    pub fn producer_at(&self, role: Role, tick: u64) -> u32 {
        let r = role as usize;
        if tick >= self.switch_tick[r] {
            self.next[r]
        } else {
            self.active[r]
        }
    }

    /// How a consumer treats a sample of `role` from `epoch` for `tick`.
    pub fn judge(&self, role: Role, epoch: u32, tick: u64) -> EpochVerdict {
        let r = role as usize;
        if epoch == self.producer_at(role, tick) {
            EpochVerdict::Take
        } else if epoch == self.active[r] || epoch == self.next[r] {
            EpochVerdict::Standby
        } else {
            EpochVerdict::Reject
        }
    }

    /// Makes `epoch` the only producer of `role`, for every tick (a restart, or a
    /// replacement that takes over at once because the process it replaces died).
    pub fn activate(&mut self, role: Role, epoch: u32) {
        let r = role as usize;
        let pins = self.pins(role, epoch).unwrap_or_default();
        self.active_publishers[r] = pins;
        self.next_publishers[r] = pins;
        self.active[r] = epoch;
        self.next[r] = epoch;
        self.switch_tick[r] = SWITCH_UNSCHEDULED;
    }

    /// The epoch producing the newest ticks of `role`.
    pub fn current(&self, role: Role) -> u32 {
        let r = role as usize;
        if self.switch_tick[r] == SWITCH_UNSCHEDULED {
            self.active[r]
        } else {
            self.next[r]
        }
    }

    /// Announces `epoch` as the replacement of the current producer of `role`, warming up.
    /// (The producer an earlier swap replaced is forgotten: its samples are rejected.)
    pub fn announce(&mut self, role: Role, epoch: u32) {
        let r = role as usize;
        let current = self.current(role);
        self.active_publishers[r] = self.pins(role, current).unwrap_or_default();
        self.next_publishers[r] = [0; 2];
        self.active[r] = current;
        self.next[r] = epoch;
        self.switch_tick[r] = SWITCH_UNSCHEDULED;
    }

    /// The publishers of `epoch` of `role` by output slot (0: not known yet), if `epoch` is
    /// named for the role.
    fn pins(&self, role: Role, epoch: u32) -> Option<[u128; 2]> {
        let r = role as usize;
        if epoch == self.next[r] {
            Some(self.next_publishers[r])
        } else if epoch == self.active[r] {
            Some(self.active_publishers[r])
        } else {
            None
        }
    }

    /// Pins the outputs of `epoch` of `role` to the publishers it announced, once: an
    /// epoch already pinned keeps its publishers (a second announcement is someone else's).
    /// Whether anything changed.
    pub fn pin(&mut self, role: Role, epoch: u32, publishers: [u128; 2]) -> bool {
        let r = role as usize;
        if self.pins(role, epoch) != Some([0; 2]) || publishers == [0; 2] {
            return false;
        }
        if epoch == self.active[r] {
            self.active_publishers[r] = publishers;
        }
        if epoch == self.next[r] {
            self.next_publishers[r] = publishers;
        }
        true
    }

    /// The publisher that output `slot` of `epoch` of `role` was pinned to, if known.
    pub fn publisher(&self, role: Role, epoch: u32, slot: usize) -> Option<u128> {
        let id = self.pins(role, epoch)?.get(slot).copied()?;
        (id != 0).then_some(id)
    }

    /// Takes the replacement of `role` from `tick` on.
    pub fn schedule_switch(&mut self, role: Role, tick: u64) {
        self.switch_tick[role as usize] = tick;
    }

    /// Calls off the switch of `role`: the active producer stays; the replacement's
    /// samples are still skipped, not rejected, as it may have some in flight.
    pub fn unschedule(&mut self, role: Role) {
        self.switch_tick[role as usize] = SWITCH_UNSCHEDULED;
    }
}

impl Control {
    pub fn command(&self) -> Option<ControlCommand> {
        Some(match self.command {
            0 => ControlCommand::Grant,
            1 => ControlCommand::Start,
            2 => ControlCommand::Stop,
            3 => ControlCommand::Epochs,
            4 => ControlCommand::Replay,
            5 => ControlCommand::Goal,
            _ => return None,
        })
    }

    /// The goals set while the run drives that it carries.
    pub fn goals(&self) -> crate::task::Goals {
        let change = |serial: u32, from_tick: u64, [x, y, yaw]: [f64; 3]| {
            (serial > 0).then_some(crate::task::GoalChange {
                serial,
                from_tick,
                goal: crate::Goal {
                    position: [x, y],
                    yaw_rad: (!yaw.is_nan()).then_some(yaw),
                },
            })
        };
        crate::task::Goals {
            prior: change(
                self.prior_goal_serial,
                self.prior_goal_from_tick,
                self.prior_goal,
            ),
            newest: change(self.goal_serial, self.goal_from_tick, self.goal),
        }
    }

    /// Carries `goals`.
    pub fn set_goals(&mut self, goals: crate::task::Goals) {
        let fields = |c: crate::task::GoalChange| {
            let [x, y] = c.goal.position;
            (
                c.serial,
                c.from_tick,
                [x, y, c.goal.yaw_rad.unwrap_or(f64::NAN)],
            )
        };
        if let Some((serial, from_tick, goal)) = goals.newest.map(fields) {
            (self.goal_serial, self.goal_from_tick, self.goal) = (serial, from_tick, goal);
        }
        if let Some((serial, from_tick, goal)) = goals.prior.map(fields) {
            (
                self.prior_goal_serial,
                self.prior_goal_from_tick,
                self.prior_goal,
            ) = (serial, from_tick, goal);
        }
    }
}

/// What a process reports to the orchestrator.
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StatusEvent {
    /// Every port is open: the process can take part in the run.
    Ready = 0,
    /// No input arrived within the input timeout; the process exits.
    InputLost = 1,
    /// Samples were rejected: `detail` is the [`Rejection`] code, `count` how many.
    Rejected = 2,
}

impl StatusEvent {
    pub fn from_code(code: u32) -> Option<StatusEvent> {
        [
            StatusEvent::Ready,
            StatusEvent::InputLost,
            StatusEvent::Rejected,
        ]
        .into_iter()
        .find(|e| *e as u32 == code)
    }
}

/// Why a consumer refused a sample (docs/design.md, "Supervision").
#[repr(u32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rejection {
    NonFinite = 0,
    TickBackwards = 1,
    WrongRun = 2,
    WrongEpoch = 3,
    /// A tick its producer cannot have reached yet: ahead of the clock (the lockstep grant,
    /// or the real-time clock's tick plus `TICK_SLACK` of the runtime).
    TickAhead = 4,
    /// A time that is not its tick's (`tick Ts / M`).
    TimeMismatch = 5,
    /// From an iceoryx2 publisher other than the one the producer announced when it joined
    /// (or, on the control topic, than the orchestrator's).
    UnknownPublisher = 6,
    /// A code, count or length outside what the message type allows
    /// ([`Message::well_formed`]).
    Malformed = 7,
    /// Of another robot than the consumer's ([`Header::robot`](crate::Header::robot)).
    WrongRobot = 8,
}

impl Rejection {
    pub const COUNT: usize = 9;
    pub const ALL: [Rejection; Rejection::COUNT] = [
        Rejection::NonFinite,
        Rejection::TickBackwards,
        Rejection::WrongRun,
        Rejection::WrongEpoch,
        Rejection::TickAhead,
        Rejection::TimeMismatch,
        Rejection::UnknownPublisher,
        Rejection::Malformed,
        Rejection::WrongRobot,
    ];
    pub fn as_str(self) -> &'static str {
        match self {
            Rejection::NonFinite => "non_finite",
            Rejection::TickBackwards => "tick_backwards",
            Rejection::WrongRun => "wrong_run",
            Rejection::WrongEpoch => "wrong_epoch",
            Rejection::TickAhead => "tick_ahead",
            Rejection::TimeMismatch => "time_mismatch",
            Rejection::UnknownPublisher => "unknown_publisher",
            Rejection::Malformed => "malformed",
            Rejection::WrongRobot => "wrong_robot",
        }
    }

    /// Whether the refusal is the fault of the sample's own producer (its run, epoch and
    /// publisher were right): what counts towards its failure
    /// (docs/design.md, "Supervision"). A stranger's samples never do.
    pub fn blames_producer(self) -> bool {
        !matches!(
            self,
            Rejection::WrongRun
                | Rejection::WrongRobot
                | Rejection::WrongEpoch
                | Rejection::UnknownPublisher
        )
    }
}

#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
#[cfg_attr(feature = "iceoryx2", derive(ZeroCopySend), type_name("scmpc::Status"))]
pub struct Status {
    pub header: Header,
    /// [`Role`] code.
    pub role: u32,
    /// [`StatusEvent`] code.
    pub event: u32,
    pub pid: u32,
    /// [`Rejection`] code for [`StatusEvent::Rejected`].
    pub detail: u32,
    pub count: u64,
    /// [`StatusEvent::Rejected`]: the [`Role`] code of the producer refused, or
    /// [`NO_PRODUCER`] (the control topic).
    pub producer: u32,
    pub reserved: u32,
    /// [`StatusEvent::Ready`]: the iceoryx2 publisher of each of the role's outputs, by
    /// [`output_slot`](crate::topics::output_slot) (0: none).
    pub publishers: [u128; 2],
}

/// [`Status::producer`] of refused samples of a topic without a producer role (control).
pub const NO_PRODUCER: u32 = u32::MAX;

/// Longest command line a live swap request carries, bytes (arguments NUL-terminated).
pub const MAX_COMMAND_BYTES: usize = 1024;
/// Longest message of a swap reply, bytes.
pub const MAX_REPLY_BYTES: usize = 256;

/// `scmpc swap` to the orchestrator: replace `role` by a process started with `command`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::SwapRequest")
)]
pub struct SwapRequest {
    pub header: Header,
    /// Chosen by the requester; the reply carries it back.
    pub request_id: u64,
    /// [`Role`] code.
    pub role: u32,
    /// Bytes of `command` used.
    pub command_len: u32,
    /// Program and arguments, each NUL-terminated; empty: the built-in process of the role.
    pub command: [u8; MAX_COMMAND_BYTES],
}

impl Default for SwapRequest {
    fn default() -> Self {
        SwapRequest {
            header: Header::default(),
            request_id: 0,
            role: 0,
            command_len: 0,
            command: [0; MAX_COMMAND_BYTES],
        }
    }
}

impl SwapRequest {
    /// A request; `None` if the command line does not fit in [`MAX_COMMAND_BYTES`] or an
    /// argument holds a NUL byte.
    pub fn new(request_id: u64, role: Role, command: &[String]) -> Option<SwapRequest> {
        let mut request = SwapRequest {
            request_id,
            role: role as u32,
            ..SwapRequest::default()
        };
        let mut at = 0;
        for arg in command {
            let bytes = arg.as_bytes();
            if bytes.contains(&0) || at + bytes.len() + 1 > MAX_COMMAND_BYTES {
                return None;
            }
            request.command[at..at + bytes.len()].copy_from_slice(bytes);
            at += bytes.len() + 1;
        }
        request.command_len = at as u32;
        Some(request)
    }

    /// Whether the command fits and is empty or UTF-8 arguments, each NUL-terminated.
    pub(super) fn command_is_well_formed(&self) -> bool {
        let len = self.command_len as usize;
        len <= MAX_COMMAND_BYTES
            && (len == 0 || self.command[len - 1] == 0)
            && std::str::from_utf8(&self.command[..len]).is_ok()
    }

    /// The command's program and arguments.
    pub fn command(&self) -> Vec<String> {
        let len = (self.command_len as usize).min(MAX_COMMAND_BYTES);
        self.command[..len]
            .strip_suffix(&[0])
            .map_or_else(Vec::new, |args| {
                args.split(|b| *b == 0)
                    .map(|arg| String::from_utf8_lossy(arg).into_owned())
                    .collect()
            })
    }
}

/// The orchestrator's answer to a [`SwapRequest`], once the swap is done or has failed.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "iceoryx2",
    derive(ZeroCopySend),
    type_name("scmpc::SwapReply")
)]
pub struct SwapReply {
    pub header: Header,
    pub request_id: u64,
    /// 1: the replacement is active; 0: the swap failed, the old process still runs.
    pub done: u32,
    /// Epoch of the replacement.
    pub epoch: u32,
    /// First tick taken from the replacement.
    pub switch_tick: u64,
    /// The iceoryx2 publisher of the request answered: the client that asked takes only
    /// the replies addressed to it.
    pub requester: u128,
    pub message_len: u32,
    pub reserved: u32,
    /// What happened, UTF-8.
    pub message: [u8; MAX_REPLY_BYTES],
}

impl Default for SwapReply {
    fn default() -> Self {
        SwapReply {
            header: Header::default(),
            request_id: 0,
            done: 0,
            epoch: 0,
            switch_tick: 0,
            requester: 0,
            message_len: 0,
            reserved: 0,
            message: [0; MAX_REPLY_BYTES],
        }
    }
}

impl SwapReply {
    /// Sets the message, cut to [`MAX_REPLY_BYTES`] at a character boundary.
    pub fn with_message(mut self, text: &str) -> SwapReply {
        let mut end = text.len().min(MAX_REPLY_BYTES);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        self.message[..end].copy_from_slice(&text.as_bytes()[..end]);
        self.message_len = end as u32;
        self
    }

    pub fn message(&self) -> String {
        let len = (self.message_len as usize).min(MAX_REPLY_BYTES);
        String::from_utf8_lossy(&self.message[..len]).into_owned()
    }
}

// The fields of the control plane's messages (`scmpc schema`'s `types`).
crate::layouts! {
    EpochSchedule {
        active: [u32; Role::COUNT],
        next: [u32; Role::COUNT],
        switch_tick: [u64; Role::COUNT],
        active_publishers: [[u128; 2]; Role::COUNT],
        next_publishers: [[u128; 2]; Role::COUNT],
    }
    Control {
        header: Header,
        command: u32,
        reserved: u32,
        start_ns: u64,
        epochs: EpochSchedule,
        goal: [f64; 3],
        goal_from_tick: u64,
        goal_serial: u32,
        prior_goal_serial: u32,
        prior_goal: [f64; 3],
        prior_goal_from_tick: u64,
        reserved_goal: [u32; 2],
    }
    Status {
        header: Header,
        role: u32,
        event: u32,
        pid: u32,
        detail: u32,
        count: u64,
        producer: u32,
        reserved: u32,
        publishers: [u128; 2],
    }
    SwapRequest {
        header: Header,
        request_id: u64,
        role: u32,
        command_len: u32,
        command: [u8; MAX_COMMAND_BYTES],
    }
    SwapReply {
        header: Header,
        request_id: u64,
        done: u32,
        epoch: u32,
        switch_tick: u64,
        requester: u128,
        message_len: u32,
        reserved: u32,
        message: [u8; MAX_REPLY_BYTES],
    }
}
