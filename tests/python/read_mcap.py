"""Reads a run.mcap with the `mcap` package (an independent reader) and prints, as JSON,
per topic: its schema name and encodings, its message count, and for some topics what the
messages hold (the estimates' ticks and epochs, the plans' pose counts)."""

import json
import sys

from mcap.reader import make_reader


def main():
    topics = {}
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
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
            if channel.topic == "/estimator/estimate":
                t.setdefault("ticks", []).append(body["tick"])
                t.setdefault("epochs", []).append(body["epoch"])
            elif channel.topic == "/mpc/plan":
                t.setdefault("poses", []).append(len(body["poses"]))
            elif channel.topic == "/world/obstacles":
                t["entities"] = {e["id"]: len(e["cylinders"]) + len(e["spheres"]) for e in body["entities"]}
            if channel.topic in ("/robot/truth", "/dfl/deadline"):
                t["log_time_ns"].append(message.log_time)
    json.dump(topics, sys.stdout)


if __name__ == "__main__":
    main()
