"""Reads a run.mcap with the `mcap` package (an independent reader) and prints, as JSON,
per topic: its schema name and encodings, its message count, and for some topics what the
messages hold (the estimates' ticks and epochs, the plans' pose counts, the events with
the errors `jsonschema` finds in them against their channel's schema, the truths' and
the deadline verdicts' log times and places in the order read).

With `--scan` it reads the records in file order with the package's non-seeking reader,
as one reads a file cut short (a killed run): every message up to the cut, and
`"cut": true` under the key `""` when the file ends inside a record or without its
footer."""

import json
import sys

from jsonschema import Draft202012Validator
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader


def messages(f, scan):
    if not scan:
        yield from make_reader(f).iter_messages()
        return
    yield from NonSeekingReader(f).iter_messages(log_time_order=False)


def main():
    topics = {}
    scan = "--scan" in sys.argv[2:]
    with open(sys.argv[1], "rb") as f:
        try:
            for position, (schema, channel, message) in enumerate(messages(f, scan)):
                add(topics, schema, channel, message, position)
        except EndOfFile:
            if not scan:
                raise
            topics[""] = {"cut": True}
    json.dump(topics, sys.stdout)


def add(topics, schema, channel, message, position):
    t = topics.setdefault(
        channel.topic,
        {
            "schema": schema.name,
            "schema_encoding": schema.encoding,
            "message_encoding": channel.message_encoding,
            "schema_is_json": bool(json.loads(schema.data)),
            "count": 0,
            "log_time_ns": [],
        },
    )
    t["count"] += 1
    body = json.loads(message.data)
    if "recorded" not in t:
        # A topic the record has no place of its own for: its time, its tick and the
        # values its message type names, each message valid under the channel's schema.
        t["recorded"] = {"t", "tick"} <= set(json.loads(schema.data).get("required", []))
    if t["recorded"]:
        validator = Draft202012Validator(json.loads(schema.data))
        t.setdefault("messages", []).append(body)
        t.setdefault("schema_errors", []).extend(e.message for e in validator.iter_errors(body))
    if channel.topic == "/estimator/estimate":
        t.setdefault("ticks", []).append(body["tick"])
        t.setdefault("epochs", []).append(body["epoch"])
    elif channel.topic == "/mpc/plan":
        t.setdefault("poses", []).append(len(body["poses"]))
    elif channel.topic in ("/world/obstacles", "/world/moving_obstacles", "/tracker/tracks"):
        t["entities"] = {e["id"]: len(e["cylinders"]) + len(e["spheres"]) for e in body["entities"]}
    elif channel.topic == "/lidar/laser_scan":
        validator = Draft202012Validator(json.loads(schema.data))
        errors = t.setdefault("schema_errors", [])
        errors.extend(e.message for e in validator.iter_errors(body))
        t.setdefault("beams", []).append(len(body["ranges"]))
        t.setdefault("returns", []).append(sum(1 for r in body["ranges"] if r != 0))
        t.setdefault("origins", []).append([body["pose"]["position"]["x"], body["pose"]["position"]["y"]])
    elif channel.topic == "/run/events":
        validator = Draft202012Validator(json.loads(schema.data))
        t.setdefault("events", []).append(body)
        errors = t.setdefault("schema_errors", [])
        errors.extend(e.message for e in validator.iter_errors(body))
    # A fleet's robot's are under its id: `/robot1/robot/truth`.
    if channel.topic.endswith(("/robot/truth", "/dfl/deadline")):
        t["log_time_ns"].append(message.log_time)
        t.setdefault("positions", []).append(position)


if __name__ == "__main__":
    main()
