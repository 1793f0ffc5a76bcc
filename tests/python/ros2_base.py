"""A simulated ROS 2 differential-drive base for tests/ros2_robot.rs, built from public
packages the project did not write: `eclipse-zenoh` for the transport and `rosbags` for
the CDR and the RIHS01 type hashes. It speaks rmw_zenoh's wire format as a Jazzy or Kilted
node would: it takes `cmd_vel` (TwistStamped or Twist) and publishes `odom` (Odometry) at
50 Hz, with an actuator lag, odometry noise and a command watchdog like
`diff_drive_controller`'s (`cmd_vel_timeout`).

`--router ENDPOINT...` runs a Zenoh router there instead (the robot's `rmw_zenohd`); with
`--tls CA CERT KEY` its `tls/` endpoints ask for mutual authentication.

On SIGTERM the base writes its log (JSON) to `--log`: its own truth, every command it
took with its attachment, when it published odometry and when it went on after a
SIGSTOP (SIGCONT), and every change of the ROS 2 graph
(liveliness tokens appearing and going) as rmw_zenoh's graph cache would parse it, and
what it saw of the pipeline's views for RViz (`scmpc/plan`, `scmpc/route`,
`scmpc/obstacles`). With `--goal X Y` it publishes that goal on `goal_pose` as RViz's
"2D Goal Pose" does, every 0.2 s until the first command comes. SIGSTOP pauses it, odometry and all.

With `--scan` it has a lidar: 360 beams all around at 10 Hz, ray-cast against its own
world (`--obstacle X Y R` standing, `--person X Y VX VY R` walking from the first command
on), published on `scan` as `sensor_msgs/msg/LaserScan` in frame `laser`, whose mount on
`base_link` (`--mount X Y YAW`) goes on `tf_static` once, through an advanced publisher
with a cache (transient local, as rmw_zenoh has done since 0.2.2). `--scan-stop-after S`:
no scan after S s from the first command. Each truth row ends with the base's clearance
from its world (the least distance from its centre to a disc's edge, m)."""

import argparse
import json
import math
import os
import random
import signal
import struct
import sys
import threading
import time
import traceback

import numpy as np
import zenoh
import zenoh.ext
from rosbags.typesys import Stores, get_typestore

STORES = {"jazzy": Stores.ROS2_JAZZY, "kilted": Stores.ROS2_KILTED}
DT_S = 0.005
ODOMETRY_EVERY = 4  # 200 Hz / 4 = 50 Hz
QOS = "::,10:,:,:,,"
SCAN_QOS = "2::,5:,:,:,,"
TF_STATIC_QOS = "1:1:,1:,:,:,,"
BEAMS = 360
SCAN_EVERY = 20  # 200 Hz / 20 = 10 Hz
RANGE_MIN_M, RANGE_MAX_M = 0.1, 8.0
# `--wire bridge`: the keys of zenoh-bridge-ros2dds, no attachments.
BRIDGE = False


def dds_name(typename):
    package, kind, name = typename.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def data_key(domain, topic, typename, store):
    if BRIDGE:
        # zenoh-bridge-ros2dds: the topic's name alone.
        return topic.strip("/")
    return f"{domain}/{topic.strip('/')}/{dds_name(typename)}/{store.hash_rihs01(typename)}"


def attachment(sequence, gid):
    return struct.pack("<qqB16s", sequence, time.time_ns(), 16, gid)


def read_attachment(data):
    if data is None or len(data) != 33 or data[16] != 16:
        return None
    sequence, stamp = struct.unpack_from("<qq", data)
    return {"sequence": sequence, "source_timestamp_ns": stamp}


def parse_token(key):
    """A liveliness token as rmw_zenoh's graph cache reads it (`liveliness_utils.cpp`):
    None when it would refuse it."""
    parts = key.split("/")
    if len(parts) < 9 or parts[0] != "@ros2_lv":
        return None
    entity = {
        "domain": int(parts[1]),
        "zid": parts[2],
        "node_id": int(parts[3]),
        "entity_id": int(parts[4]),
        "kind": parts[5],
        "enclave": parts[6].replace("%", "/"),
        "namespace": parts[7].replace("%", "/"),
        "node": parts[8],
    }
    if entity["kind"] == "NN":
        return entity if len(parts) == 9 else None
    if entity["kind"] not in ("MP", "MS", "SS", "SC") or len(parts) != 13:
        return None
    qos = parts[12].split(":")
    if len(qos) != 6 or len(qos[2].split(",")) != 2 or len(qos[5].split(",")) != 3:
        return None
    history_depth = qos[2].split(",")[1]
    entity.update(
        topic=parts[9].replace("%", "/"),
        type=parts[10],
        type_hash=parts[11],
        reliable=qos[0] in ("", "1"),
        depth=int(history_depth) if history_depth else 42,
    )
    return entity


class Base:
    def __init__(self, args, store):
        self.args = args
        self.store = store
        self.lock = threading.Lock()
        x, y, yaw = args.start
        self.pose = [x, y, yaw]
        self.speed = [0.0, 0.0]  # what the wheels do: forward m/s, turn rad/s
        self.wanted = [0.0, 0.0]
        self.last_command = None  # monotonic s
        self.commands = []
        self.refused = 0
        self.truth = []
        self.odometry_ns = []
        self.scans_ns = []
        self.first_command = None  # monotonic s
        self.rng = random.Random(args.seed)

    def on_command(self, sample):
        attached = read_attachment(
            sample.attachment.to_bytes() if sample.attachment is not None else None
        )
        if attached is None and BRIDGE:
            attached = {}
        if attached is None:
            with self.lock:
                self.refused += 1
            return
        message = self.store.deserialize_cdr(sample.payload.to_bytes(), self.args.command_type)
        twist = message.twist if hasattr(message, "twist") else message
        with self.lock:
            self.wanted = [twist.linear.x, twist.angular.z]
            self.last_command = time.monotonic()
            if self.first_command is None:
                self.first_command = self.last_command
            self.commands.append(
                dict(
                    attached,
                    received_ns=time.time_ns(),
                    forward=twist.linear.x,
                    turn=twist.angular.z,
                    frame_id=message.header.frame_id if hasattr(message, "header") else None,
                )
            )

    def step(self):
        """One step of the wheels (first-order lag) and the unicycle."""
        with self.lock:
            quiet = self.last_command is None or (
                time.monotonic() - self.last_command > self.args.watchdog_s
            )
            wanted = [0.0, 0.0] if quiet else list(self.wanted)
            alpha = DT_S / (self.args.lag_s + DT_S)
            self.speed = [s + alpha * (w - s) for s, w in zip(self.speed, wanted)]
            v, w = self.speed
            x, y, yaw = self.pose
            self.pose = [x + DT_S * v * math.cos(yaw), y + DT_S * v * math.sin(yaw), yaw + DT_S * w]
            self.truth.append([time.time_ns(), *self.pose, v, w, self.clearance(self.pose)])

    def walked_s(self):
        return 0.0 if self.first_command is None else time.monotonic() - self.first_command

    def discs(self):
        """The world's discs now: `[x, y, r]`."""
        t = self.walked_s()
        people = [[x + vx * t, y + vy * t, r] for x, y, vx, vy, r in self.args.person or []]
        return [list(o) for o in self.args.obstacle or []] + people

    def clearance(self, pose):
        x, y = pose[0], pose[1]
        return min((math.hypot(x - ox, y - oy) - r for ox, oy, r in self.discs()), default=1e9)

    def ranges(self):
        """One exact ray cast per beam from the lidar's place, with 1 cm of noise."""
        with self.lock:
            x, y, yaw = self.pose
            discs = self.discs()
        mx, my, myaw = self.args.mount
        lx = x + math.cos(yaw) * mx - math.sin(yaw) * my
        ly = y + math.sin(yaw) * mx + math.cos(yaw) * my
        ranges = np.full(BEAMS, np.inf, dtype=np.float32)
        for i in range(BEAMS):
            heading = yaw + myaw - math.pi + 2 * math.pi * i / BEAMS
            dx, dy = math.cos(heading), math.sin(heading)
            for ox, oy, r in discs:
                fx, fy = ox - lx, oy - ly
                along = fx * dx + fy * dy
                across2 = fx * fx + fy * fy - along * along
                if along > 0 and across2 < r * r:
                    hit = along - math.sqrt(r * r - across2)
                    if RANGE_MIN_M <= hit <= RANGE_MAX_M:
                        ranges[i] = min(ranges[i], hit + self.rng.gauss(0.0, 0.01))
        return ranges

    def odometry(self):
        t = self.store.types
        noise = self.args.noise_std
        with self.lock:
            x, y, yaw = (p + self.rng.gauss(0.0, noise) for p in self.pose)
            v, w = self.speed
        now = time.time_ns()
        covariance = np.zeros(36, dtype=np.float64)
        return t["nav_msgs/msg/Odometry"](
            header=t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=now // 10**9, nanosec=now % 10**9),
                frame_id="odom",
            ),
            child_frame_id="base_link",
            pose=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=t["geometry_msgs/msg/Pose"](
                    position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
                    orientation=t["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
                    ),
                ),
                covariance=covariance,
            ),
            twist=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=t["geometry_msgs/msg/Twist"](
                    linear=t["geometry_msgs/msg/Vector3"](x=v, y=0.0, z=0.0),
                    angular=t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=w),
                ),
                covariance=covariance,
            ),
        )


def laser_scan(store, ranges):
    t = store.types
    now = time.time_ns()
    return t["sensor_msgs/msg/LaserScan"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=now // 10**9, nanosec=now % 10**9),
            frame_id="laser",
        ),
        angle_min=-math.pi,
        angle_max=math.pi - 2 * math.pi / BEAMS,
        angle_increment=2 * math.pi / BEAMS,
        time_increment=0.0,
        scan_time=0.1,
        range_min=RANGE_MIN_M,
        range_max=RANGE_MAX_M,
        ranges=ranges,
        intensities=np.zeros(0, dtype=np.float32),
    )


def mount(store, x, y, yaw):
    t = store.types
    return t["tf2_msgs/msg/TFMessage"](
        transforms=[
            t["geometry_msgs/msg/TransformStamped"](
                header=t["std_msgs/msg/Header"](
                    stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="base_link"
                ),
                child_frame_id="laser",
                transform=t["geometry_msgs/msg/Transform"](
                    translation=t["geometry_msgs/msg/Vector3"](x=x, y=y, z=0.2),
                    rotation=t["geometry_msgs/msg/Quaternion"](
                        x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)
                    ),
                ),
            )
        ]
    )


def goal_pose(store, x, y):
    t = store.types
    return t["geometry_msgs/msg/PoseStamped"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="odom"
        ),
        pose=t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=x, y=y, z=0.0),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        ),
    )


def config(mode, listen=(), connect=()):
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    # No shared memory: it would leave files in /dev/shm, and the robot is on the network.
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return conf


def wait_for_term():
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    return done


def router(endpoints, tls):
    done = wait_for_term()
    conf = config("router", listen=endpoints)
    if tls:
        # TLS with mutual authentication, as a robot's rmw_zenohd would be set up.
        ca, certificate, key = tls
        for name, value in [
            ("root_ca_certificate", ca),
            ("listen_certificate", certificate),
            ("listen_private_key", key),
            ("enable_mtls", True),
        ]:
            conf.insert_json5(f"transport/link/tls/{name}", json.dumps(value))
    session = zenoh.open(conf)
    print("router ready", flush=True)
    done.wait()
    session.close()


def base(args):
    store = get_typestore(STORES[args.distro])
    args.command_type = (
        "geometry_msgs/msg/TwistStamped" if args.stamped else "geometry_msgs/msg/Twist"
    )
    done = wait_for_term()
    resumed_ns = []
    signal.signal(signal.SIGCONT, lambda *_: resumed_ns.append(time.time_ns()))
    conf = config("peer", connect=[args.connect])
    # An advanced publisher's cache (tf_static) stamps its samples.
    conf.insert_json5("timestamping/enabled", "true")
    session = zenoh.open(conf)
    zid = str(session.zid())
    the_base = Base(args, store)
    cmd_key = data_key(args.domain, args.cmd_vel, args.command_type, store)
    odom_key = data_key(args.domain, args.odom, "nav_msgs/msg/Odometry", store)
    subscriber = session.declare_subscriber(cmd_key, the_base.on_command)
    publisher = session.declare_publisher(odom_key)
    node = f"@ros2_lv/{args.domain}/{zid}/0"
    tokens = [
        session.liveliness().declare_token(f"{node}/0/NN/%/%/base"),
        session.liveliness().declare_token(
            f"{node}/1/MP/%/%/base/%{args.odom.strip('/')}/{dds_name('nav_msgs/msg/Odometry')}/"
            f"{store.hash_rihs01('nav_msgs/msg/Odometry')}/{QOS}"
        ),
        session.liveliness().declare_token(
            f"{node}/2/MS/%/%/base/%{args.cmd_vel.strip('/')}/{dds_name(args.command_type)}/"
            f"{store.hash_rihs01(args.command_type)}/{QOS}"
        ),
    ]
    scan_publisher = None
    if args.scan:
        scan_key = data_key(args.domain, "scan", "sensor_msgs/msg/LaserScan", store)
        tf_key = data_key(args.domain, "tf_static", "tf2_msgs/msg/TFMessage", store)
        scan_publisher = session.declare_publisher(scan_key)
        tf_publisher = zenoh.ext.declare_advanced_publisher(
            session, tf_key, cache=zenoh.ext.CacheConfig(max_samples=1)
        )
        tf_payload = bytes(store.serialize_cdr(mount(store, *args.mount), "tf2_msgs/msg/TFMessage"))
        tf_publisher.put(tf_payload, attachment=attachment(1, bytes(16)))
        tokens += [
            session.liveliness().declare_token(
                f"{node}/3/MP/%/%/base/%scan/{dds_name('sensor_msgs/msg/LaserScan')}/"
                f"{store.hash_rihs01('sensor_msgs/msg/LaserScan')}/{SCAN_QOS}"
            ),
            session.liveliness().declare_token(
                f"{node}/4/MP/%/%/base/%tf_static/{dds_name('tf2_msgs/msg/TFMessage')}/"
                f"{store.hash_rihs01('tf2_msgs/msg/TFMessage')}/{TF_STATIC_QOS}"
            ),
        ]
        the_base.scan_cdr = lambda: bytes(
            store.serialize_cdr(laser_scan(store, the_base.ranges()), "sensor_msgs/msg/LaserScan")
        )
        the_base.scan_cdr()
    graph = []

    def on_token(sample):
        key = str(sample.key_expr)
        with the_base.lock:
            graph.append(
                {
                    "token": key,
                    "alive": sample.kind == zenoh.SampleKind.PUT,
                    "parsed": parse_token(key),
                }
            )

    watcher = session.liveliness().declare_subscriber(
        f"@ros2_lv/{args.domain}/**", on_token, history=True
    )
    views = {}

    def viewer(name, typename):
        def on_view(sample):
            message = store.deserialize_cdr(sample.payload.to_bytes(), typename)
            with the_base.lock:
                seen = views.setdefault(name, {"count": 0})
                seen["count"] += 1
                if typename == "nav_msgs/msg/Path":
                    seen["frame_id"] = message.header.frame_id
                    seen["last"] = [[p.pose.position.x, p.pose.position.y] for p in message.poses]
                else:
                    seen["last"] = [
                        [m.pose.position.x, m.pose.position.y, m.scale.x, m.type]
                        for m in message.markers
                    ]

        key = data_key(args.domain, f"scmpc/{name}", typename, store)
        return session.declare_subscriber(key, on_view)

    viewers = [
        viewer("plan", "nav_msgs/msg/Path"),
        viewer("route", "nav_msgs/msg/Path"),
        viewer("obstacles", "visualization_msgs/msg/MarkerArray"),
    ]
    goal_publisher = session.declare_publisher(
        data_key(args.domain, "goal_pose", "geometry_msgs/msg/PoseStamped", store)
    )
    gid = bytes(random.Random(args.seed).getrandbits(8) for _ in range(16))
    # rosbags makes a type's (de)serializer on its first use: not while the base drives.
    the_base.odometry_cdr = lambda: bytes(
        store.serialize_cdr(the_base.odometry(), "nav_msgs/msg/Odometry")
    )
    the_base.odometry_cdr()
    t = store.types
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    command = t["geometry_msgs/msg/Twist"](linear=zero, angular=zero)
    if args.stamped:
        stamp = t["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
        header = t["std_msgs/msg/Header"](stamp=stamp, frame_id="")
        command = t["geometry_msgs/msg/TwistStamped"](header=header, twist=command)
    payload = bytes(store.serialize_cdr(command, args.command_type))
    store.deserialize_cdr(payload, args.command_type)
    print("base ready", flush=True)
    sequence = 0
    next_s = time.monotonic()
    steps = 0
    while not done.is_set():
        the_base.step()
        steps += 1
        if args.goal and not the_base.commands and steps % 40 == 0:
            # RViz's "2D Goal Pose", clicked again until the robot moves.
            payload = bytes(store.serialize_cdr(goal_pose(store, *args.goal), "geometry_msgs/msg/PoseStamped"))
            goal_publisher.put(payload, attachment=attachment(steps, gid))
        if steps % ODOMETRY_EVERY == 0:
            sequence += 1
            publisher.put(
                the_base.odometry_cdr(),
                attachment=None if BRIDGE else attachment(sequence, gid),
            )
            the_base.odometry_ns.append(time.time_ns())
        stopped = args.scan_stop_after is not None and the_base.walked_s() > args.scan_stop_after
        if scan_publisher is not None and steps % SCAN_EVERY == 0 and not stopped:
            scan_publisher.put(the_base.scan_cdr(), attachment=attachment(steps, gid))
            the_base.scans_ns.append(time.time_ns())
        next_s += DT_S
        time.sleep(max(0.0, next_s - time.monotonic()))
    # Commands sent while the base was paused are still queued in its socket when SIGCONT
    # and SIGTERM come together: take them all (no command for 0.3 s; 5 s at most).
    quiet_since = time.monotonic()
    seen = len(the_base.commands)
    while time.monotonic() - quiet_since < 0.3 and time.monotonic() - next_s < 5.0:
        time.sleep(0.02)
        with the_base.lock:
            if len(the_base.commands) != seen:
                seen, quiet_since = len(the_base.commands), time.monotonic()
    with the_base.lock:
        log = {
            "truth": the_base.truth,
            "commands": the_base.commands,
            "refused_commands": the_base.refused,
            "odometry_ns": the_base.odometry_ns,
            "scans_ns": the_base.scans_ns,
            "resumed_ns": resumed_ns,
            "views": views,
            "graph": graph,
            "command_key": cmd_key,
            "odometry_key": odom_key,
        }
    with open(args.log, "w") as f:
        json.dump(log, f)
    del subscriber, tokens, watcher, viewers
    session.close()


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--router", nargs="+")
    parser.add_argument("--tls", nargs=3, metavar=("CA", "CERT", "KEY"))
    parser.add_argument("--connect")
    parser.add_argument("--log")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--distro", default="jazzy")
    parser.add_argument("--cmd-vel", default="cmd_vel")
    parser.add_argument("--odom", default="odom")
    parser.add_argument("--twist", dest="stamped", action="store_false")
    parser.add_argument("--start", type=float, nargs=3, default=[0.0, 0.0, 0.0])
    parser.add_argument("--lag-s", type=float, default=0.05)
    parser.add_argument("--noise-std", type=float, default=0.002)
    parser.add_argument("--watchdog-s", type=float, default=0.5)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--goal", type=float, nargs=2)
    parser.add_argument("--wire", choices=["rmw_zenoh", "bridge"], default="rmw_zenoh")
    parser.add_argument("--scan", action="store_true")
    parser.add_argument("--mount", type=float, nargs=3, default=[0.0, 0.0, 0.0])
    parser.add_argument("--obstacle", type=float, nargs=3, action="append")
    parser.add_argument("--person", type=float, nargs=5, action="append")
    parser.add_argument("--scan-stop-after", type=float)
    args = parser.parse_args()
    global BRIDGE
    BRIDGE = args.wire == "bridge"
    if args.router:
        router(args.router, args.tls)
    else:
        base(args)


if __name__ == "__main__":
    try:
        main()
    except BaseException:
        # Zenoh's threads would keep a failed base alive: print why and go.
        traceback.print_exc()
        sys.stderr.flush()
        os._exit(1)
    sys.stdout.flush()
    os._exit(0)
