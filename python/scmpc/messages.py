"""ctypes mirrors of the messages that cross scmpc's process boundaries.

Each mirrors a ``#[repr(C)]`` type of the Rust crate ``protocol`` byte for byte; ``scmpc
schema`` prints the Rust layouts and the test ``tests/python.rs`` compares them with these.
Rust aligns ``u128`` to 16 bytes and ctypes has no 128-bit integer: :class:`U128` is two
``u64`` (little-endian), and the padding Rust puts before it is written out as ``_pad``
fields. Such a type's ctypes alignment is 8 where Rust's is 16; iceoryx2 accepts a smaller
alignment when opening a service the orchestrator created.
"""

import ctypes
import math

c_u8 = ctypes.c_uint8
c_u32 = ctypes.c_uint32
c_u64 = ctypes.c_uint64
c_f32 = ctypes.c_float
c_f64 = ctypes.c_double

MAX_HORIZON = 64
ROUTE_CAPACITY = 64
MAX_TRACKS = 32
MAX_BEAMS = 1440
MAX_COMMAND_BYTES = 1024
MAX_REPLY_BYTES = 256
SWITCH_UNSCHEDULED = 2**64 - 1
NO_PRODUCER = 2**32 - 1
PLAN_MISSING = 2**32 - 1

# Header.robot of a run's one robot (a role instance is a role and a robot id).
FIRST_ROBOT = 0

# Codes of the enumerations (``scmpc schema``, "codes").
ROLES = {"plant": 0, "estimator": 1, "mpc": 2, "dfl": 3, "planner": 4, "tracker": 5, "odometer": 6, "lidar": 7}
ROLE_COUNT = len(ROLES)
CONTROL_COMMANDS = {"grant": 0, "start": 1, "stop": 2, "epochs": 3, "replay": 4, "goal": 5}
STATUS_EVENTS = {"ready": 0, "input_lost": 1, "rejected": 2}
REJECTIONS = {
    "non_finite": 0,
    "tick_backwards": 1,
    "wrong_run": 2,
    "wrong_epoch": 3,
    "tick_ahead": 4,
    "time_mismatch": 5,
    "unknown_publisher": 6,
    "malformed": 7,
    "wrong_robot": 8,
}
PLAN_STATUSES = {"solved": 0, "infeasible": 1, "max_iterations": 2, "numerical_error": 3}
COMMAND_MODES = {
    "nominal": 0,
    "shifted": 1,
    "brake": 2,
    "zeta_guard": 3,
    "safety_brake": 4,
    "hold": 5,
    "evasion": 6,
    "watchdog": 7,
}
INTERVENTIONS = {"none": 0, "plan_refused": 1, "committed_unsafe": 2, "least_unsafe": 3, "moving_contact": 4, "free_range": 5, "evasion": 6}
ROUTE_STATUSES = {"ok": 0, "no_route": 1}
REPLAN_REASONS = {"start": 0, "period": 1, "stall": 2, "stray": 3}
ROUTE_SWITCHES = {"replanned": 0, "same_way": 1, "shorter": 2, "blocked": 3}
# Where each output sits in the publishers a producer announces (Status.publishers).
OUTPUT_SLOTS = {
    "truth": 0,
    "measurement": 1,
    "estimate": 0,
    "plan": 0,
    "actuation": 0,
    "deadline": 1,
    "route": 0,
    "tracks": 0,
    "scan": 0,
    "odometry": 0,
}


# Where iceoryx2 keeps a run's service and node files (its ``config.global.root_path``;
# ``scmpc schema``, "root_path").
ROOT_PATH = "/dev/shm/iceoryx2/"

# The tick topics whose samples at sample starts are announced on a second event service,
# ``<service>/sample_starts`` (``scmpc schema``, "services"): a publisher notifies it too.
SAMPLE_START_TOPICS = ("truth", "estimate")


def sample_starts_service(service):
    """The event service of the samples at sample starts of service ``service``."""
    return f"{service}/sample_starts"


def service_name(robot, topic):
    """The iceoryx2 service of ``topic`` of robot ``robot`` (a robot's pipeline is under
    ``robot<id>/``; ``scmpc schema``, "services")."""
    return f"robot{robot}/{topic}"


class U128(ctypes.Structure):
    """A Rust ``u128`` as two little-endian ``u64`` (8-byte aligned; see the module docs)."""

    _fields_ = [("lo", c_u64), ("hi", c_u64)]

    @staticmethod
    def type_name():
        return "u128"

    @property
    def value(self):
        return self.lo | (self.hi << 64)

    @value.setter
    def value(self, v):
        self.lo = v & (2**64 - 1)
        self.hi = v >> 64


class Message(ctypes.Structure):
    """A message type: its iceoryx2 type name is ``scmpc::<class name>``."""

    @classmethod
    def type_name(cls):
        return "scmpc::" + cls.__name__

    def floats(self):
        """Every float the border check requires finite (besides the header's time)."""
        return ()

    def well_formed(self):
        """Whether every code, count and length is one the type allows."""
        return True

    def all_finite(self):
        return math.isfinite(self.header.time_s) and all(map(math.isfinite, self.floats()))


class Header(Message):
    _fields_ = [
        ("tick", c_u64),
        ("time_s", c_f64),
        ("publish_ns", c_u64),
        ("epoch", c_u32),
        ("input_latency_ns", c_u32),
        ("run_id", c_u32),
        ("robot", c_u32),
    ]


class EpochSchedule(Message):
    _fields_ = [
        ("active", c_u32 * ROLE_COUNT),
        ("next", c_u32 * ROLE_COUNT),
        ("switch_tick", c_u64 * ROLE_COUNT),
        ("active_publishers", (U128 * 2) * ROLE_COUNT),
        ("next_publishers", (U128 * 2) * ROLE_COUNT),
    ]

    def producer_at(self, role, tick):
        """The producer epoch whose samples of ``tick`` are taken."""
        return self.next[role] if tick >= self.switch_tick[role] else self.active[role]

    def judge(self, role, epoch, tick):
        """``"take"``, ``"standby"`` (a producer swapped in or out: skipped) or ``"reject"``."""
        if epoch == self.producer_at(role, tick):
            return "take"
        if epoch in (self.active[role], self.next[role]):
            return "standby"
        return "reject"

    def publisher(self, role, epoch, slot):
        """The publisher id output ``slot`` of ``epoch`` of ``role`` is pinned to, if known."""
        if epoch == self.next[role]:
            pins = self.next_publishers[role]
        elif epoch == self.active[role]:
            pins = self.active_publishers[role]
        else:
            return None
        return pins[slot].value or None

    def key(self, role):
        return (self.active[role], self.next[role], self.switch_tick[role])


class Measurement(Message):
    _fields_ = [("header", Header), ("y", c_f64 * 3), ("odometry", c_f64 * 2)]

    def floats(self):
        return list(self.y) + list(self.odometry)


class GroundTruth(Message):
    _fields_ = [("header", Header), ("pose", c_f64 * 3), ("applied", c_f64 * 2), ("watchdog", c_u32), ("reserved", c_u32)]

    def floats(self):
        return list(self.pose) + list(self.applied)


class Estimate(Message):
    _fields_ = [
        ("header", Header),
        ("state", c_f64 * 4),
        ("covariance", c_f64 * 9),
        ("ahead", c_f64 * 4),
    ]

    def floats(self):
        return (*self.state, *self.covariance, *self.ahead)


class Plan(Message):
    _fields_ = [
        ("header", Header),
        ("sample", c_u64),
        ("status", c_u32),
        ("horizon", c_u32),
        ("solve_ns", c_u64),
        ("iterations", c_u32),
        ("solves", c_u32),
        ("gives_way", c_u32),
        ("reserved", c_u32),
        ("injected_delay_ns", c_u64),
        ("v", (c_f64 * 2) * MAX_HORIZON),
        ("z", (c_f64 * 4) * (MAX_HORIZON + 1)),
    ]

    def floats(self):
        n = min(self.horizon, MAX_HORIZON)
        return [x for v in self.v[:n] for x in v] + [x for z in self.z[: n + 1] for x in z]

    def well_formed(self):
        return self.horizon <= MAX_HORIZON and self.status in PLAN_STATUSES.values()


class Route(Message):
    _fields_ = [
        ("header", Header),
        ("sample", c_u64),
        ("planned_sample", c_u64),
        ("status", c_u32),
        ("count", c_u32),
        ("plans", c_u32),
        ("reason", c_u32),
        ("switch", c_u32),
        ("reserved", c_u32),
        ("length_m", c_f64),
        ("plan_ns", c_u64),
        ("waypoints", (c_f64 * 2) * ROUTE_CAPACITY),
    ]

    def floats(self):
        n = min(self.count, ROUTE_CAPACITY)
        return [self.length_m] + [x for p in self.waypoints[:n] for x in p]

    def well_formed(self):
        ok = {ROUTE_STATUSES["ok"]: self.count >= 2, ROUTE_STATUSES["no_route"]: self.count == 0}
        return (
            self.count <= ROUTE_CAPACITY
            and self.reason in REPLAN_REASONS.values()
            and self.switch in ROUTE_SWITCHES.values()
            and ok.get(self.status, False)
        )


class Track(Message):
    _fields_ = [
        ("obstacle", c_u32),
        ("reserved", c_u32),
        ("radius_m", c_f64),
        ("center", c_f64 * 2),
        ("velocity", c_f64 * 2),
        ("covariance", c_f64 * 6),
    ]


class Tracks(Message):
    _fields_ = [
        ("header", Header),
        ("count", c_u32),
        ("dropped", c_u32),
        ("tracks", Track * MAX_TRACKS),
    ]

    def floats(self):
        n = min(self.count, MAX_TRACKS)
        return [
            x
            for t in self.tracks[:n]
            for x in (t.radius_m, *t.center, *t.velocity, *t.covariance)
        ]

    def well_formed(self):
        return self.count <= MAX_TRACKS


class Actuation(Message):
    _fields_ = [
        ("header", Header),
        ("u1", c_f64),
        ("u2", c_f64),
        ("wheels", c_f64 * 2),
        ("linearizing_input", c_f64 * 2),
        ("zeta", c_f64),
        ("v", c_f64 * 2),
        ("mode", c_u32),
        ("deadline_misses", c_u32),
        ("plan_sample", c_u64),
        ("intervention", c_u32),
        ("safety_interventions", c_u32),
        ("intervention_plan", c_u64),
        ("intervention_clearance_m", c_f64),
    ]

    def floats(self):
        return (self.u1, self.u2, self.zeta, *self.wheels, *self.linearizing_input, *self.v)

    def well_formed(self):
        return self.mode in COMMAND_MODES.values() and self.intervention in INTERVENTIONS.values()


class Scan(Message):
    _fields_ = [
        ("header", Header),
        ("beams", c_u32),
        ("age_ticks", c_u32),
        ("angle_min_rad", c_f64),
        ("angle_increment_rad", c_f64),
        ("range_min_m", c_f64),
        ("range_max_m", c_f64),
        ("offset", c_f64 * 3),
        ("ranges_m", c_f32 * MAX_BEAMS),
    ]

    def floats(self):
        # Ranges are REP 117's: +-inf and NaN are values, not faults.
        return (
            self.angle_min_rad,
            self.angle_increment_rad,
            self.range_min_m,
            self.range_max_m,
            *self.offset,
        )

    def well_formed(self):
        return self.beams <= MAX_BEAMS


class Odometry(Message):
    _fields_ = [
        ("header", Header),
        ("distance_m", c_f64),
    ]

    def floats(self):
        return (self.distance_m,)


class DeadlineVerdict(Message):
    _fields_ = [
        ("header", Header),
        ("sample", c_u64),
        ("met", c_u32),
        ("status", c_u32),
        ("production_ns", c_u64),
        ("arrival_ns", c_u64),
        ("fallback", c_u32),
        ("misses_total", c_u32),
    ]

    def well_formed(self):
        return (
            self.met <= 1
            and (self.status == PLAN_MISSING or self.status in PLAN_STATUSES.values())
            and self.fallback in COMMAND_MODES.values()
        )


class Control(Message):
    _fields_ = [
        ("header", Header),
        ("command", c_u32),
        ("reserved", c_u32),
        ("start_ns", c_u64),
        ("_pad", c_u8 * 8),
        ("epochs", EpochSchedule),
        ("goal", c_f64 * 3),
        ("goal_from_tick", c_u64),
        ("goal_serial", c_u32),
        ("prior_goal_serial", c_u32),
        ("prior_goal", c_f64 * 3),
        ("prior_goal_from_tick", c_u64),
        ("reserved_goal", c_u32 * 2),
    ]

    def well_formed(self):
        return self.command in CONTROL_COMMANDS.values()


class Status(Message):
    _fields_ = [
        ("header", Header),
        ("role", c_u32),
        ("event", c_u32),
        ("pid", c_u32),
        ("detail", c_u32),
        ("count", c_u64),
        ("producer", c_u32),
        ("reserved", c_u32),
        ("_pad", c_u8 * 8),
        ("publishers", U128 * 2),
    ]


class SwapRequest(Message):
    _fields_ = [
        ("header", Header),
        ("request_id", c_u64),
        ("role", c_u32),
        ("command_len", c_u32),
        ("command", c_u8 * MAX_COMMAND_BYTES),
    ]


class SwapReply(Message):
    _fields_ = [
        ("header", Header),
        ("request_id", c_u64),
        ("done", c_u32),
        ("epoch", c_u32),
        ("switch_tick", c_u64),
        ("requester", U128),
        ("message_len", c_u32),
        ("reserved", c_u32),
        ("message", c_u8 * MAX_REPLY_BYTES),
        ("_pad", c_u8 * 8),
    ]


# Every topic and the type it carries (``scmpc schema``, "services").
TOPICS = {
    "measurement": Measurement,
    "truth": GroundTruth,
    "estimate": Estimate,
    "plan": Plan,
    "actuation": Actuation,
    "deadline": DeadlineVerdict,
    "route": Route,
    "tracks": Tracks,
    "scan": Scan,
    "odometry": Odometry,
    "control": Control,
    "status": Status,
    "swap": SwapRequest,
    "swap_reply": SwapReply,
}

# Every type, nested ones first, as ``scmpc schema`` lists them.
TYPES = [
    Header,
    EpochSchedule,
    Measurement,
    GroundTruth,
    Estimate,
    Plan,
    Route,
    Actuation,
    DeadlineVerdict,
    Track,
    Tracks,
    Scan,
    Odometry,
    Control,
    Status,
    SwapRequest,
    SwapReply,
]
