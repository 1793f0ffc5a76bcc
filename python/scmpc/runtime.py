"""The role runtime in Python: the rules every built-in role process follows.

The Rust role runtime (``protocol::runtime`` and ``protocol::ipc``) is what this mirrors;
a Python role writes only a step function (see ``examples/python/estimator.py``):

- It joins the run named by the ``SCMPC_*`` environment the orchestrator starts it with
  (:class:`RoleArgs`), on the run's iceoryx2 prefix, as node ``<role>-<epoch>``.
- It stamps every sample with its epoch, the run's id and the publish time
  (:class:`Sender`), and announces its publishers in its ``ready`` status: consumers take
  its samples from those alone.
- It takes control messages from the orchestrator's publisher alone, and follows the
  epoch schedule they carry: while it warms up as a replacement its samples are skipped
  by its consumers (standby), from its switch tick on they are taken.
- Every input sample passes the border check (:meth:`Receiver.check`): the run, the
  producer's epoch and publisher, finite values and well-formed codes, a tick the clock
  allows, a time that is its tick's, ticks in order. Refused samples are counted and
  reported to the orchestrator by reason.
- On ``Replay`` it publishes its newest sample of each output again (a process that just
  joined gets what it missed); on ``Stop``, SIGINT or SIGTERM it exits; it exits when the
  orchestrator is gone (at once in lockstep, after :data:`ORPHAN_GRACE_S` in real time)
  or when no input came for :data:`INPUT_TIMEOUT_S`.
"""

import os
import time
import tomllib

import iceoryx2 as iox2

from . import messages as m

INPUT_TIMEOUT_S = 5.0
SUPERVISOR_CHECK_S = 0.1
ORPHAN_GRACE_S = 1.5
# Real time: ticks a sample may be ahead of the wall clock's tick.
TICK_SLACK = 2
# Lockstep: ticks a sample may be ahead of the newest grant heard.
GRANT_IN_FLIGHT = 1
TIME_TOLERANCE_S = 1e-6
MAX_PUBLISHERS = 4
MAX_STATUS_PUBLISHERS = 8
MAX_SUBSCRIBERS = 8
SUBSCRIBER_BUFFER = 64


def _clock_shift_ns():
    """The shift of this process's clock (docs/hosts.md): an artificial offset in
    ``SCMPC_CLOCK_OFFSET_MS`` and the correction to the orchestrator's clock that a host's
    agent gives its role processes in ``SCMPC_CLOCK_CORRECTION_NS``."""
    offset_ms = float(os.environ.get("SCMPC_CLOCK_OFFSET_MS", "").strip() or 0)
    correction_ns = float(os.environ.get("SCMPC_CLOCK_CORRECTION_NS", "").strip() or 0)
    return round(offset_ms * 1e6 + correction_ns)


CLOCK_SHIFT_NS = _clock_shift_ns()


def monotonic_ns():
    """The run's clock, ns: ``CLOCK_MONOTONIC`` shifted to the orchestrator's on every host;
    the clock of every header's ``publish_ns`` and of ``start_ns``."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC) + CLOCK_SHIFT_NS


def run_id(prefix):
    """The run's identity stamped on every sample: ``SCMPC_RUN_ID`` (hexadecimal) on a host
    of its own, else FNV-1a of its prefix."""
    if os.environ.get("SCMPC_RUN_ID", "").strip():
        return int(os.environ["SCMPC_RUN_ID"], 16)
    h = 0x811C9DC5
    for b in prefix.encode():
        h = ((h ^ b) * 0x01000193) & 0xFFFFFFFF
    return h


def process_alive(pid):
    """Whether process ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return False
    return stat[stat.rfind(b") ") + 2 : stat.rfind(b") ") + 3] != b"Z"


class RoleArgs:
    """What the orchestrator starts a role process with, from its ``SCMPC_*`` environment."""

    def __init__(self, environ=os.environ):
        def need(name):
            if name not in environ:
                raise SystemExit(f"scmpc role: {name} is not set (start this with `scmpc swap`)")
            return environ[name]

        with open(need("SCMPC_SCENARIO"), "rb") as f:
            self.scenario = tomllib.load(f)
        self.prefix = need("SCMPC_PREFIX")
        self.mode = need("SCMPC_MODE")
        if self.mode not in ("lockstep", "realtime"):
            raise SystemExit(f"scmpc role: SCMPC_MODE={self.mode}: lockstep or realtime")
        self.epoch = int(need("SCMPC_EPOCH"))
        self.role = need("SCMPC_ROLE")
        # The robot whose pipeline this process is part of (its services, Header.robot).
        self.robot = int(environ.get("SCMPC_ROBOT", "").strip() or m.FIRST_ROBOT)
        pid = environ.get("SCMPC_SUPERVISOR_PID")
        self.supervisor_pid = int(pid) if pid else None
        control = environ.get("SCMPC_CONTROL_PUBLISHER")
        self.control_publisher = int(control, 16) if control else None
        timing = self.scenario["timing"]
        self.ts_s = float(timing["ts_s"])
        self.inner_steps = int(timing["inner_steps"])
        self.dt_s = self.ts_s / self.inner_steps

    @property
    def lockstep(self):
        return self.mode == "lockstep"


class ControlState:
    """What the orchestrator has said so far."""

    def __init__(self):
        self.granted = None
        self.start_ns = None
        self.stopped = False
        self.replay = False
        self.schedule = None
        self.clock_tick = None
        self.orphaned = False

    def apply(self, c):
        self.schedule = m.EpochSchedule.from_buffer_copy(c.epochs)
        tick = c.header.tick
        self.clock_tick = tick if self.clock_tick is None else max(self.clock_tick, tick)
        command = c.command
        if command == m.CONTROL_COMMANDS["grant"]:
            self.granted = tick
        elif command == m.CONTROL_COMMANDS["start"]:
            self.start_ns = c.start_ns
        elif command == m.CONTROL_COMMANDS["stop"]:
            self.stopped = True
        elif command == m.CONTROL_COMMANDS["replay"]:
            self.replay = True

    def at_ns(self, offset_s):
        """Real time: the monotonic time ``offset_s`` after the run's start (None before)."""
        return None if self.start_ns is None else self.start_ns + int(offset_s * 1e9)


def _open_topic(node, robot, name, payload):
    service_name = iox2.ServiceName.new(m.service_name(robot, name))
    pubsub = (
        node.service_builder(service_name)
        .publish_subscribe(payload)
        .max_publishers(MAX_STATUS_PUBLISHERS if name == "status" else MAX_PUBLISHERS)
        .max_subscribers(MAX_SUBSCRIBERS)
        .subscriber_max_buffer_size(SUBSCRIBER_BUFFER)
        .history_size(0)
        .enable_safe_overflow(True)
        .open_or_create()
    )
    event = node.service_builder(service_name).event().open_or_create()
    return pubsub, event


def _sample_starts_notifier(node, robot, name):
    """The notifier of the samples at sample starts of topic ``name``, if it announces them."""
    if name not in m.SAMPLE_START_TOPICS:
        return None
    service = m.sample_starts_service(m.service_name(robot, name))
    event = node.service_builder(iox2.ServiceName.new(service)).event().open_or_create()
    return event.notifier_builder().create()


class Sender:
    """Publishes one topic, stamping epoch, run id and publish time, and wakes its listeners
    (those woken at sample starts only by the samples whose tick is a multiple of
    ``ticks_per_sample``)."""

    def __init__(self, node, name, epoch, run, robot, ticks_per_sample=1):
        self.name = name
        self.payload = m.TOPICS[name]
        pubsub, event = _open_topic(node, robot, name, self.payload)
        self.publisher = pubsub.publisher_builder().create()
        self.notifier = event.notifier_builder().create()
        self.sample_starts = _sample_starts_notifier(node, robot, name)
        self.ticks_per_sample = max(1, ticks_per_sample)
        self.epoch = epoch
        self.run_id = run
        self.robot = robot
        self.last = None

    @property
    def publisher_id(self):
        return self.publisher.id.value

    def send(self, message):
        message.header.epoch = self.epoch
        message.header.run_id = self.run_id
        message.header.robot = self.robot
        message.header.publish_ns = monotonic_ns()
        self.last = message
        self.publisher.send_copy(message)
        self.notifier.notify()
        if self.sample_starts is not None and message.header.tick % self.ticks_per_sample == 0:
            self.sample_starts.notify()

    def replay(self):
        """Publishes the newest sample again (same tick, fresh publish time)."""
        if self.last is not None:
            self.send(self.last)


class Receiver:
    """Takes the samples of one topic that pass the border check (module docs)."""

    def __init__(self, node, name, run, robot, producer=None, clock=None):
        self.name = name
        self.payload = m.TOPICS[name]
        pubsub, event = _open_topic(node, robot, name, self.payload)
        self.subscriber = pubsub.subscriber_builder().buffer_size(SUBSCRIBER_BUFFER).create()
        self.listener = event.listener_builder().create()
        self.run_id = run
        self.robot = robot
        self.producer = None if producer is None else m.ROLES[producer]
        self.slot = m.OUTPUT_SLOTS.get(name) if producer is not None else None
        self.clock = clock
        self.pinned = None
        self.schedule = None
        self.last_tick = None
        self.rejected = [0] * len(m.REJECTIONS)

    def follow(self, schedule):
        """Takes samples by ``schedule`` from now on; ticks are checked afresh when the
        producers of the role change."""
        if self.producer is None:
            return
        if self.schedule is None or self.schedule.key(self.producer) != schedule.key(self.producer):
            self.last_tick = None
        self.schedule = schedule

    def receive(self):
        """The next acceptable sample and its publish-to-receipt latency (ns), or None."""
        if self.producer is not None and (self.schedule is None or not self.clock.known()):
            return None
        while True:
            sample = self.subscriber.receive()
            if sample is None:
                return None
            message = self.payload.from_buffer_copy(sample.payload().contents)
            origin = sample.header.publisher_id.value
            latency = max(0, monotonic_ns() - message.header.publish_ns)
            verdict = self.check(message, origin)
            if verdict == "take":
                return message, latency
            if verdict != "standby":
                self.rejected[m.REJECTIONS[verdict]] += 1

    def take(self):
        """Every pending acceptable sample, oldest first."""
        taken = []
        while (received := self.receive()) is not None:
            taken.append(received)
        return taken

    def check(self, message, origin):
        """``"take"``, ``"standby"`` or the name of the rejection (the Rust border check)."""
        h = message.header
        if h.run_id != self.run_id:
            return "wrong_run"
        if h.robot != self.robot:
            return "wrong_robot"
        if self.pinned is not None and origin != self.pinned:
            return "unknown_publisher"

        def content():
            if not message.all_finite():
                return "non_finite"
            if not message.well_formed():
                return "malformed"
            return None

        if self.producer is None or self.schedule is None:
            return content() or "take"
        verdict = self.schedule.judge(self.producer, h.epoch, h.tick)
        if verdict == "reject":
            return "wrong_epoch"
        pin = self.schedule.publisher(self.producer, h.epoch, self.slot)
        if pin is not None and pin != origin:
            return "unknown_publisher"
        if verdict == "standby":
            return "standby"
        refused = content()
        if refused:
            return refused
        newest = self.clock.newest_tick(False)
        if newest is None or h.tick > newest:
            newest = self.clock.newest_tick(True)
            if newest is None or h.tick > newest:
                return "tick_ahead"
        if abs(h.time_s - h.tick * self.clock.dt_s) > TIME_TOLERANCE_S:
            return "time_mismatch"
        if self.last_tick is not None and h.tick < self.last_tick:
            return "tick_backwards"
        self.last_tick = h.tick
        return "take"

    def take_rejections(self):
        counts, self.rejected = self.rejected, [0] * len(m.REJECTIONS)
        return counts

    def clear_wakeups(self):
        self.listener.try_wait()


class RoleClock:
    """The control topic and what it has said: "now" as far as this process knows it."""

    def __init__(self, control, mode, dt_s):
        self.control = control
        self.state = ControlState()
        self.mode = mode
        self.dt_s = dt_s

    def take(self):
        for c, _ in self.control.take():
            self.state.apply(c)

    def known(self):
        s = self.state
        return (s.clock_tick if self.mode == "lockstep" else s.start_ns) is not None

    def newest_tick(self, refresh):
        if refresh:
            self.take()
        s = self.state
        if self.mode == "lockstep":
            return None if s.clock_tick is None else s.clock_tick + GRANT_IN_FLIGHT
        if s.start_ns is None:
            return None
        elapsed = max(0, monotonic_ns() - s.start_ns)
        return int(elapsed / (self.dt_s * 1e9)) + TICK_SLACK


class Link:
    """A role process's connection to the run: its node, its clock and its status reports."""

    def __init__(self, args, role=None):
        self.args = args
        self.role = role or args.role
        if self.role not in m.ROLES:
            raise SystemExit(f"scmpc role: unknown role `{self.role}`")
        iox2.set_log_level(iox2.LogLevel.Error)
        config = iox2.config.default()
        config.global_cfg.root_path = iox2.Path.new(m.ROOT_PATH)
        config.global_cfg.prefix = iox2.FileName.new(args.prefix)
        # Only the orchestrator cleans up after dead nodes (it must see every death).
        config.global_cfg.node.cleanup_dead_nodes_on_creation = False
        config.global_cfg.node.cleanup_dead_nodes_on_destruction = False
        config.global_cfg.service.cleanup_dead_nodes_on_open = False
        self.node = (
            iox2.NodeBuilder.new()
            .config(config)
            .name(iox2.NodeName.new(f"{self.role}-{args.epoch}"))
            .signal_handling_mode(iox2.SignalHandlingMode.HandleTerminationRequests)
            .create(iox2.ServiceType.Ipc)
        )
        self.run_id = run_id(args.prefix)
        control = Receiver(self.node, "control", self.run_id, args.robot)
        control.pinned = args.control_publisher
        self.clock = RoleClock(control, args.mode, args.dt_s)
        self.status = Sender(self.node, "status", args.epoch, self.run_id, args.robot)

    def input(self, name, producer):
        """Samples of topic ``name`` from the active process of role ``producer``."""
        return Receiver(self.node, name, self.run_id, self.args.robot, producer, self.clock)

    def output(self, name):
        args = self.args
        return Sender(self.node, name, args.epoch, self.run_id, args.robot, args.inner_steps)

    def _status(self, event, **fields):
        status = m.Status(role=m.ROLES[self.role], event=m.STATUS_EVENTS[event], pid=os.getpid())
        for key, value in fields.items():
            setattr(status, key, value)
        return status

    def _report_rejections(self, counts, producer):
        for code, count in enumerate(counts):
            if count:
                self.status.send(
                    self._status(
                        "rejected",
                        detail=code,
                        count=count,
                        producer=m.NO_PRODUCER if producer is None else producer,
                    )
                )

    def run(self, inputs, outputs, step):
        """Runs the role until the orchestrator stops it, a signal comes, or it is orphaned.

        ``step(state)`` is called on every wake-up with the :class:`ControlState`; it takes
        from ``inputs``, publishes on ``outputs`` and returns how long to wait at most (s)
        before it is called again, or None to wait for an input.
        """
        waitset = (
            iox2.WaitSetBuilder.new()
            .signal_handling_mode(iox2.SignalHandlingMode.HandleTerminationRequests)
            .create(iox2.ServiceType.Ipc)
        )
        guards = [waitset.attach_notification(r.listener) for r in [self.clock.control, *inputs]]
        ready = self._status("ready")
        for output in outputs:
            slot = m.OUTPUT_SLOTS.get(output.name)
            if slot is not None:
                ready.publishers[slot].value = output.publisher_id
        self.status.send(ready)
        followed = None
        last_input = time.monotonic()
        checked = time.monotonic()
        orphaned_at = None
        try:
            while True:
                # Before the step: the newest control messages, the newest schedule.
                self.clock.take()
                state = self.clock.state
                if state.schedule is not None and (
                    followed is None or bytes(state.schedule) != bytes(followed)
                ):
                    for r in inputs:
                        r.follow(state.schedule)
                    followed = state.schedule
                timeout_s = step(state)
                # After it: wake-ups consumed, control drained, refusals reported, replay.
                for r in [*inputs, self.clock.control]:
                    r.clear_wakeups()
                self.clock.take()
                for r in inputs:
                    if state.schedule is not None:
                        r.follow(state.schedule)
                    self._report_rejections(r.take_rejections(), r.producer)
                self._report_rejections(self.clock.control.take_rejections(), None)
                if state.stopped:
                    return
                if state.replay:
                    state.replay = False
                    for output in outputs:
                        output.replay()
                if any(r.subscriber.has_samples() for r in inputs):
                    continue
                now = time.monotonic()
                if orphaned_at is not None:
                    if now - orphaned_at >= ORPHAN_GRACE_S:
                        return
                elif now - checked >= SUPERVISOR_CHECK_S:
                    checked = now
                    pid = self.args.supervisor_pid
                    if pid is not None and not process_alive(pid):
                        if self.args.lockstep:
                            return
                        orphaned_at = now
                        state.orphaned = True
                wait_s = min(INPUT_TIMEOUT_S if timeout_s is None else timeout_s, SUPERVISOR_CHECK_S)
                fired, result = waitset.wait_and_process_with_timeout(
                    iox2.Duration.from_secs_f64(max(wait_s, 0.0))
                )
                if result in (iox2.WaitSetRunResult.TerminationRequest, iox2.WaitSetRunResult.Interrupt):
                    return
                if fired:
                    last_input = time.monotonic()
                elif time.monotonic() - last_input >= INPUT_TIMEOUT_S:
                    self.status.send(self._status("input_lost"))
                    raise SystemExit(f"scmpc {self.role}: no input for {INPUT_TIMEOUT_S} s")
        finally:
            del guards


def keep_newest(newest, sample):
    """The one of ``newest`` and ``sample`` with the higher tick (``newest`` may be None)."""
    if newest is None or sample.header.tick >= newest.header.tick:
        return sample
    return newest


__all__ = [
    "ControlState",
    "Link",
    "Receiver",
    "RoleArgs",
    "Sender",
    "keep_newest",
    "monotonic_ns",
    "run_id",
]
