#!/usr/bin/env python3
"""An scmpc state estimator in plain Python: the extended Kalman filter of the built-in one.

Swap it in for the running estimator (README, "A role in Python"):

    scmpc swap --run DIR estimator -- python3 examples/python/estimator.py

On each measurement it predicts the pose with the actuation of the previous tick (the
unicycle over one tick, exact for a constant turn rate), corrects it with the measurement
and publishes the estimate with the covariance. In lockstep a measurement waits until the
actuation of the tick before it has been heard; in real time the newest heard is used.
"""

import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))

from scmpc import Estimate, Link, RoleArgs, keep_newest  # noqa: E402

MIN_MEASUREMENT_VARIANCE = 1e-12


def wrap_angle(theta):
    """Wraps an angle to (-pi, pi]."""
    w = math.fmod(theta + math.pi, 2 * math.pi)
    w = w + 2 * math.pi if w < 0 else w
    w -= math.pi
    return w + 2 * math.pi if w <= -math.pi else w


def matmul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def transpose(a):
    return [list(row) for row in zip(*a)]


def add(a, b):
    return [[a[i][j] + b[i][j] for j in range(3)] for i in range(3)]


def inverse(a):
    """The inverse of a 3x3 matrix, or None if it is singular."""
    (p, q, r), (s, t, u), (v, w, x) = a
    cof = [
        [t * x - u * w, -(q * x - r * w), q * u - r * t],
        [-(s * x - u * v), p * x - r * v, -(p * u - r * s)],
        [s * w - t * v, -(p * w - q * v), p * t - q * s],
    ]
    det = p * cof[0][0] + q * cof[1][0] + r * cof[2][0]
    if det == 0.0 or not math.isfinite(det):
        return None
    return [[c / det for c in row] for row in cof]


def diagonal(d):
    return [[d[i] if i == j else 0.0 for j in range(3)] for i in range(3)]


def per_axis(variance):
    return list(variance) if isinstance(variance, list) else [float(variance)] * 3


class Ekf:
    """Pose ``[x, y, theta]`` and its covariance: predict with ``(u1, u2)``, correct with ``y``."""

    def __init__(self, y, scenario):
        est = scenario["estimator"]
        noise = per_axis(scenario["plant"]["noise_variance"])
        self.mean = list(y)
        self.covariance = diagonal(est["initial_variance"])
        self.process_noise_rate = diagonal(est["process_noise"])
        self.measurement_noise = diagonal([max(v, MIN_MEASUREMENT_VARIANCE) for v in noise])

    def predict(self, u1, u2, dt_s):
        x, y, theta = self.mean
        half_turn = 0.5 * u2 * dt_s
        sinc = 1.0 if abs(half_turn) < 1e-9 else math.sin(half_turn) / half_turn
        chord = u1 * dt_s * sinc
        s, c = math.sin(theta + half_turn), math.cos(theta + half_turn)
        self.mean = [x + chord * c, y + chord * s, theta + u2 * dt_s]
        f = [[1.0, 0.0, -chord * s], [0.0, 1.0, chord * c], [0.0, 0.0, 1.0]]
        q = [[v * dt_s for v in row] for row in self.process_noise_rate]
        self.covariance = add(matmul(matmul(f, self.covariance), transpose(f)), q)

    def update(self, y):
        innovation = [y[i] - self.mean[i] for i in range(3)]
        innovation[2] = wrap_angle(innovation[2])
        s_inv = inverse(add(self.covariance, self.measurement_noise))
        if s_inv is None:
            return
        gain = matmul(self.covariance, s_inv)
        self.mean = [self.mean[i] + sum(gain[i][k] * innovation[k] for k in range(3)) for i in range(3)]
        self.mean[2] = wrap_angle(self.mean[2])
        i_k = [[(1.0 if i == j else 0.0) - gain[i][j] for j in range(3)] for i in range(3)]
        self.covariance = add(
            matmul(matmul(i_k, self.covariance), transpose(i_k)),
            matmul(matmul(gain, self.measurement_noise), transpose(gain)),
        )


def realized_inputs(plant, u1, u2):
    """``(u1, u2)`` as the wheels realize them: each wheel clipped to its limit, if set."""
    limit = plant["max_wheel_speed_rad_s"]
    if limit <= 0.0:
        return u1, u2
    r, b = plant["wheel_radius_m"], plant["wheel_base_m"]
    right = max(-limit, min(limit, (u1 + 0.5 * b * u2) / r))
    left = max(-limit, min(limit, (u1 - 0.5 * b * u2) / r))
    return 0.5 * r * (right + left), r * (right - left) / b


def main():
    args = RoleArgs()
    scenario = args.scenario
    link = Link(args, "estimator")
    measurements = link.input("measurement", "plant")
    actuation = link.input("actuation", "dfl")
    estimates = link.output("estimate")
    ekf = None
    state = {"heard": None, "last_tick": None, "queue": []}

    def step(ctl):
        state["queue"].extend(measurements.take())
        for a, _ in actuation.take():
            state["heard"] = keep_newest(state["heard"], a)
        queue, heard = state["queue"], state["heard"]
        nonlocal ekf
        while queue:
            m, latency = queue[0]
            tick = m.header.tick
            last = state["last_tick"]
            if last is not None and tick <= last:
                queue.pop(0)  # a replay of a tick already estimated
                continue
            previous = heard if heard is not None and heard.header.tick < tick else None
            # Lockstep: the actuation of tick - 1 is still on its way (not so for the first
            # measurement, or once a newer actuation was heard).
            if (
                args.lockstep
                and last is not None
                and (previous is None or previous.header.tick + 1 != tick)
                and (heard is None or heard.header.tick < tick)
            ):
                break
            queue.pop(0)
            state["last_tick"] = tick
            if ekf is None:
                ekf = Ekf(m.y, scenario)
            else:
                if previous is not None and tick > 0:
                    u1, u2 = realized_inputs(scenario["plant"], previous.u1, previous.u2)
                    ekf.predict(u1, u2, args.dt_s)
                ekf.update(m.y)
            # The DFL's zeta; started mid-run, or without the actuation (late), the base's
            # speed as its odometry says.
            if tick == 0:
                zeta = scenario["robot"]["zeta0"]
            elif previous is not None and last is not None and previous.header.tick + 1 == tick:
                zeta = previous.zeta
            else:
                zeta = m.odometry[0]
            estimate = Estimate()
            estimate.header.tick = tick
            estimate.header.time_s = m.header.time_s
            estimate.header.input_latency_ns = min(latency, 2**32 - 1)
            estimate.state[:] = [*ekf.mean, zeta]
            estimate.covariance[:] = [c for row in ekf.covariance for c in row]
            # The state once the commands in flight act: the same without a command delay
            # (this estimator models none; robot.command_delay_s needs the built-in one).
            estimate.ahead[:] = estimate.state
            estimates.send(estimate)
        return None

    link.run([measurements, actuation], [estimates], step)


if __name__ == "__main__":
    main()
