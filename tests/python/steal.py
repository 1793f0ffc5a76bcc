"""Stalls of the machine on purpose: what a busy hypervisor does to a shared VM.

Per CPU, a process pinned to it at SCHED_FIFO 99 sleeps a random GAP ms, then keeps the
CPU for a random BURN ms, until this script is stopped (Ctrl-C, SIGTERM). Nothing of a
run beats it, as nothing in a guest beats steal time; the real-time tests' FIFO 99
watchers see each burn as a stall (tests/common/stalls.rs). Needs the real-time policy
(root, or `ulimit -r 99`). Standard library only.

    python3 tests/python/steal.py --gap-ms 30 200 --burn-ms 4 25 &
    cargo test --release --test suite -- --exact swap::realtime_swaps_of_...

(docs/performance.md, "Real-time tests on a busy VM").
"""

import argparse
import os
import random
import signal
import sys
import time


def burn_on(cpu, gap_ms, burn_ms, parent):
    os.sched_setaffinity(0, {cpu})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(99))
    rng = random.Random(cpu)
    while os.getppid() == parent:
        time.sleep(rng.uniform(*gap_ms) / 1000.0)
        until = time.monotonic() + rng.uniform(*burn_ms) / 1000.0
        while time.monotonic() < until:
            pass


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gap-ms", nargs=2, type=float, default=[30.0, 200.0])
    parser.add_argument("--burn-ms", nargs=2, type=float, default=[4.0, 25.0])
    args = parser.parse_args()
    parent = os.getpid()
    children = []
    for cpu in sorted(os.sched_getaffinity(0)):
        pid = os.fork()
        if pid == 0:
            try:
                burn_on(cpu, args.gap_ms, args.burn_ms, parent)
            except PermissionError as e:
                print(f"steal.py: CPU {cpu}: SCHED_FIFO 99 refused: {e}", file=sys.stderr)
            os._exit(0)
        children.append(pid)

    def stop(*_):
        for pid in children:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        sys.exit(0)

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    for _ in children:
        os.wait()


if __name__ == "__main__":
    main()
