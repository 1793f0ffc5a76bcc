"""The peer of tests/ros2_wire.rs: `rosbags` (a CDR and REP 2011 implementation the
project did not write) reads what the crate `ros2` writes.

Arguments: ROS type names (`nav_msgs/msg/Odometry`). Standard input: lines `TYPE HEX`, a
message's CDR payload. Prints JSON: `hashes` (distro -> type -> RIHS01, as rosbags
computes them for Jazzy and Kilted) and, per input line, the message as rosbags
deserializes it (plain fields) and whether serializing it again gives the same bytes."""

import json
import sys

from rosbags.typesys import Stores, get_typestore


def plain(value):
    """A message as JSON: dataclass fields by name, arrays as lists."""
    if hasattr(value, "__dataclass_fields__"):
        return {
            name: plain(getattr(value, name))
            for name in value.__dataclass_fields__
            if not name.startswith("__")
        }
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def main():
    stores = {
        "jazzy": get_typestore(Stores.ROS2_JAZZY),
        "kilted": get_typestore(Stores.ROS2_KILTED),
    }
    hashes = {
        distro: {name: store.hash_rihs01(name) for name in sys.argv[1:]}
        for distro, store in stores.items()
    }
    jazzy = stores["jazzy"]
    messages = []
    for line in sys.stdin:
        if not line.strip():
            continue
        typename, payload = line.split()
        data = bytes.fromhex(payload)
        message = jazzy.deserialize_cdr(data, typename)
        again = bytes(jazzy.serialize_cdr(message, typename))
        messages.append(
            {"type": typename, "same_bytes": again == data, "message": plain(message)}
        )
    print(json.dumps({"hashes": hashes, "messages": messages}))


if __name__ == "__main__":
    main()
