#!/usr/bin/env python3
"""How far each new plan of a run departs from the plan before it, read from its run.mcap.

    python3 examples/python/plan_departure.py RUN_DIR [--json]

Needs the `mcap` package (`pip install mcap==1.6.0`). RUN_DIR is what `scmpc run --out`
wrote (one robot or a fleet): its `run.mcap` and its `scenario.toml` (for the sample
period). For every robot, each plan on `/mpc/plan` (`/robotK/mpc/plan` in a fleet) is
laid over the one it follows: its stage k against the earlier plan's stage at the same
time (k plus the samples between them). A step whose programs all failed publishes a
plan of zero states, recorded with every pose at (0, 0): such plans are left out, and
the plan after one is laid over the last plan found. Printed per robot, in metres, over all such
pairs: the median, 90th and 99th percentile and the largest of how far the first stage
lies from the earlier plan's (where the estimate came out against the plan's own
prediction) and of the farthest stage of the pair (how far a new plan moved from the
last; what a promise to keep to one's plan would have to allow, docs/fleet.md).

Two more measures, per plan, size such a promise at the plan's last stage: how far any
later plan published within its horizon lies from it there (a chain of promises, each to
the plan before, must allow this much), and the radius of the smallest disc holding the
plan's last stage and everywhere a brake begun at any time along the plan would have
taken the robot by then (straight on along its velocity at `dfl.brake_decel` until at
rest, as the DFL brakes). The plan's velocities are taken from its stages' differences.
"""

import json
import math
import os
import random
import sys
import tomllib
from collections import defaultdict

from mcap.reader import make_reader

QUANTILES = (0.5, 0.9, 0.99, 1.0)
# How often along a plan a brake is begun, s.
BRAKE_EVERY_S = 0.005


def plans(mcap_path):
    """{robot: [(time_s, [(x, y), ...]), ...]} in log-time order."""
    found = defaultdict(list)
    with open(mcap_path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            topic = channel.topic
            if not topic.endswith("/mpc/plan"):
                continue
            robot = topic[: -len("/mpc/plan")].lstrip("/") or "robot"
            plan = json.loads(message.data)
            stamp = plan["timestamp"]
            time_s = stamp["sec"] + stamp["nsec"] * 1e-9
            stages = [(p["position"]["x"], p["position"]["y"]) for p in plan["poses"]]
            if any(stage != (0.0, 0.0) for stage in stages):
                found[robot].append((time_s, stages))
    return found


def departures(robot_plans, ts_s):
    """(first stage, farthest stage) of each plan against the one before it, m, and how
    many samples apart the pairs are ({samples: pairs})."""
    first, farthest, shifts = [], [], defaultdict(int)
    for (t0, earlier), (t1, later) in zip(robot_plans, robot_plans[1:]):
        shift = round((t1 - t0) / ts_s)
        apart = [math.dist(p, earlier[k + shift]) for k, p in enumerate(later) if k + shift < len(earlier)]
        if shift >= 1 and apart:
            first.append(apart[0])
            farthest.append(max(apart))
            shifts[shift] += 1
    return first, farthest, dict(shifts)


def chained(robot_plans, ts_s):
    """For each plan, the farthest any later plan within its horizon lies from its last
    stage, m (plans with no later one within their horizon left out)."""
    by_sample = {round(t / ts_s): stages for t, stages in robot_plans}
    found = []
    for sample, stages in by_sample.items():
        last = len(stages) - 1
        later = [by_sample.get(sample + j) for j in range(1, last + 1)]
        apart = [math.dist(p[last - j], stages[last]) for j, p in enumerate(later, 1) if p and last - j < len(p)]
        if apart:
            found.append(max(apart))
    return found


def velocities(stages, ts_s):
    """Each stage's velocity from its neighbours, m/s (one-sided at the ends)."""
    last = len(stages) - 1
    found = []
    for k in range(last + 1):
        lo, hi = max(0, k - 1), min(last, k + 1)
        span = (hi - lo) * ts_s
        found.append(((stages[hi][0] - stages[lo][0]) / span, (stages[hi][1] - stages[lo][1]) / span))
    return found


def brake_reach(stages, ts_s, brake_decel):
    """The radius of the smallest disc holding the plan's last stage and where a brake
    begun at any time along the plan would have taken the robot by then, m."""
    last = len(stages) - 1
    velocity = velocities(stages, ts_s)
    end_s = last * ts_s
    points = [stages[last]]
    for i in range(round(end_s / BRAKE_EVERY_S)):
        t = i * BRAKE_EVERY_S
        k = min(int(t / ts_s), last - 1)
        f = t / ts_s - k
        p = [stages[k][a] + f * (stages[k + 1][a] - stages[k][a]) for a in (0, 1)]
        v = [velocity[k][a] + f * (velocity[k + 1][a] - velocity[k][a]) for a in (0, 1)]
        speed, left_s = math.hypot(*v), end_s - t
        # At rest before the plan's end, or still braking there.
        if speed <= brake_decel * left_s:
            run_m = speed * speed / (2 * brake_decel)
        else:
            run_m = speed * left_s - brake_decel * left_s * left_s / 2
        points.append(tuple(p[a] + v[a] / speed * run_m if speed > 0 else p[a] for a in (0, 1)))
    return smallest_disc(points)[1]


def smallest_disc(points):
    """(centre, radius) of the smallest disc holding every point (Welzl's algorithm, in a
    fixed shuffled order)."""
    points = list(points)
    random.Random(0).shuffle(points)
    disc = (points[0], 0.0)
    for i, p in enumerate(points):
        if math.dist(disc[0], p) <= disc[1] + 1e-12:
            continue
        disc = (p, 0.0)
        for j, q in enumerate(points[:i]):
            if math.dist(disc[0], q) <= disc[1] + 1e-12:
                continue
            disc = two_point_disc(p, q)
            for r in points[:j]:
                if math.dist(disc[0], r) > disc[1] + 1e-12:
                    disc = three_point_disc(p, q, r)
    return disc


def two_point_disc(a, b):
    centre = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
    return centre, math.dist(a, centre)


def three_point_disc(a, b, c):
    d = 2 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]))
    if abs(d) < 1e-14:  # in a line: the widest pair's
        return max((two_point_disc(a, b), two_point_disc(a, c), two_point_disc(b, c)), key=lambda x: x[1])
    n = [p[0] * p[0] + p[1] * p[1] for p in (a, b, c)]
    x = (n[0] * (b[1] - c[1]) + n[1] * (c[1] - a[1]) + n[2] * (a[1] - b[1])) / d
    y = (n[0] * (c[0] - b[0]) + n[1] * (a[0] - c[0]) + n[2] * (b[0] - a[0])) / d
    return (x, y), math.dist(a, (x, y))


def quantiles(values):
    ordered = sorted(values)
    if not ordered:
        return [None] * len(QUANTILES)
    return [ordered[min(len(ordered) - 1, int(q * len(ordered)))] for q in QUANTILES]


def main():
    args = [a for a in sys.argv[1:] if a != "--json"]
    if len(args) != 1:
        sys.exit(__doc__)
    run_dir = args[0]
    with open(os.path.join(run_dir, "scenario.toml"), "rb") as f:
        scenario = tomllib.load(f)
    ts_s = scenario["timing"]["ts_s"]
    brake_decel = scenario["dfl"]["brake_decel"]
    if brake_decel == "auto":
        brake_decel = scenario["mpc"]["v_max"]
    report = {}
    for robot, robot_plans in sorted(plans(os.path.join(run_dir, "run.mcap")).items()):
        first, farthest, shifts = departures(robot_plans, ts_s)
        report[robot] = {
            "plans": len(robot_plans),
            "pairs": len(first),
            "samples_apart": shifts,
            "first_stage_m": quantiles(first),
            "farthest_stage_m": quantiles(farthest),
            "chained_last_stage_m": quantiles(chained(robot_plans, ts_s)),
            "brake_reach_m": quantiles([brake_reach(stages, ts_s, brake_decel) for _, stages in robot_plans]),
        }
    if "--json" in sys.argv[1:]:
        print(json.dumps(report))
        return
    keys = ("first_stage_m", "farthest_stage_m", "chained_last_stage_m", "brake_reach_m")
    print("p50/p90/p99/max, m:")
    print("robot     plans   first stage           farthest stage        chained, last stage   brake's reach")
    for robot, r in report.items():
        cells = [" ".join("-" if v is None else f"{v:.3f}" for v in r[key]) for key in keys]
        print(f"{robot:<9} {r['plans']:>5}   " + " ".join(f"{c:<21}" for c in cells))


if __name__ == "__main__":
    main()
