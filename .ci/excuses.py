"""Prints what the real-time tests excused (tests/common/stalls.rs): one line per judged
run and the totals. Usage: python3 .ci/excuses.py target/tmp/excused.jsonl"""

import json
import sys


def main(path):
    try:
        with open(path) as f:
            lines = [json.loads(line) for line in f if line.strip()]
    except FileNotFoundError:
        print(f"stall excuses: no real-time test judged a run ({path} absent)")
        return
    print(
        f"stall excuses: {len(lines)} real-time runs judged (at most 1 % of a run's ticks may be "
        f"excused; a test runs again, up to 3 attempts, while the machine is too busy to judge)"
    )
    ticks = excused = stalls = elsewhere = failed = too_busy = 0
    for line in lines:
        if "too_busy" in line:
            too_busy += 1
            print(f"  {line['test']}: attempt {line['attempt']} too busy to judge: {line['too_busy'][:300]}")
            continue
        if "failed" in line:
            failed += 1
            print(f"  {line['test']}: FAILED: {line['failed'][:300]}")
            continue
        ticks += line["ticks"]
        excused += line["excused_ticks"]
        stalls += line["stalls"]
        elsewhere += line["stalls_elsewhere"]
        share = 100.0 * line["excused_ticks"] / max(line["ticks"], 1)
        print(
            f"  {line['test']}: {line['excused_ticks']} of {line['ticks']} ticks excused "
            f"({share:.2f} %), {line['faults']} faults, {line['stalls']} stalls on the run's CPUs, "
            f"{line['stalls_elsewhere']} elsewhere"
        )
    share = 100.0 * excused / max(ticks, 1)
    print(
        f"stall excuses in all: {excused} of {ticks} ticks ({share:.3f} %), {stalls} stalls on "
        f"the runs' CPUs, {elsewhere} elsewhere, {too_busy} attempts too busy to judge (run "
        f"again), {failed} runs failed their judgement"
    )


if __name__ == "__main__":
    main(sys.argv[1])
