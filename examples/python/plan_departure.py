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
"""

import json
import math
import os
import sys
import tomllib
from collections import defaultdict

from mcap.reader import make_reader

QUANTILES = (0.5, 0.9, 0.99, 1.0)


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
        ts_s = tomllib.load(f)["timing"]["ts_s"]
    report = {}
    for robot, robot_plans in sorted(plans(os.path.join(run_dir, "run.mcap")).items()):
        first, farthest, shifts = departures(robot_plans, ts_s)
        report[robot] = {
            "plans": len(robot_plans),
            "pairs": len(first),
            "samples_apart": shifts,
            "first_stage_m": quantiles(first),
            "farthest_stage_m": quantiles(farthest),
        }
    if "--json" in sys.argv[1:]:
        print(json.dumps(report))
        return
    print("robot     plans   first stage p50/p90/p99/max (m)    farthest stage p50/p90/p99/max (m)")
    for robot, r in report.items():
        cells = [" ".join("-" if v is None else f"{v:.3f}" for v in r[key]) for key in ("first_stage_m", "farthest_stage_m")]
        print(f"{robot:<9} {r['plans']:>5}   {cells[0]:<34} {cells[1]}")


if __name__ == "__main__":
    main()
