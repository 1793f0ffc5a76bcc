"""Compares the ctypes mirrors of python/scmpc with the layouts `scmpc schema` prints (on
stdin); prints every difference and exits 1 if there is one."""

import ctypes
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "python"))

from scmpc import messages  # noqa: E402

SCALARS = {
    ctypes.c_uint8: "u8",
    ctypes.c_uint32: "u32",
    ctypes.c_uint64: "u64",
    ctypes.c_float: "f32",
    ctypes.c_double: "f64",
}


def rust_type(t):
    """The Rust spelling of a ctypes type, as `scmpc schema` writes it."""
    if t in SCALARS:
        return SCALARS[t]
    if issubclass(t, ctypes.Array):
        return f"[{rust_type(t._type_)}; {t._length_}]"
    return t.type_name()


def layout(t):
    fields = []
    for name, field_type in t._fields_:
        if name.startswith("_pad"):
            continue
        fields.append(
            {
                "name": name,
                "offset": getattr(t, name).offset,
                "type": rust_type(field_type),
                "size": ctypes.sizeof(field_type),
            }
        )
    return {"size": ctypes.sizeof(t), "fields": fields}


def main():
    schema = json.load(sys.stdin)
    problems = []
    rust_types = {t["type_name"]: t for t in schema["types"]}
    python_types = {t.type_name(): t for t in messages.TYPES}
    if set(rust_types) != set(python_types):
        problems.append(f"types: Rust {sorted(rust_types)}, Python {sorted(python_types)}")
    for name in sorted(set(rust_types) & set(python_types)):
        rust, py = rust_types[name], python_types[name]
        mine = layout(py)
        if mine["size"] != rust["size"]:
            problems.append(f"{name}: size {mine['size']}, Rust {rust['size']}")
        # iceoryx2 lets a port ask for less alignment than the service has, not more.
        if ctypes.alignment(py) > rust["alignment"]:
            problems.append(f"{name}: alignment {ctypes.alignment(py)} > Rust {rust['alignment']}")
        if mine["fields"] != rust["fields"]:
            problems.append(f"{name}: fields\n  Python {mine['fields']}\n  Rust   {rust['fields']}")
    topics = {s["topic"]: s["type_name"] for s in schema["services"]}
    for s in schema["services"]:
        expected = messages.service_name(messages.FIRST_ROBOT, s["topic"]) if s["per_robot"] else s["topic"]
        if s["service"] != expected:
            problems.append(f"service of {s['topic']}: Rust {s['service']}")
        announced = s["topic"] in messages.SAMPLE_START_TOPICS
        expected = messages.sample_starts_service(s["service"]) if announced else None
        if s["sample_starts"] != expected:
            problems.append(f"sample starts of {s['topic']}: Rust {s['sample_starts']}, Python {expected}")
    if schema["root_path"] != messages.ROOT_PATH:
        problems.append(f"root path: Rust {schema['root_path']}, Python {messages.ROOT_PATH}")
    mirrored = {name: t.type_name() for name, t in messages.TOPICS.items()}
    if topics != mirrored:
        problems.append(f"services: Rust {topics}, Python {mirrored}")
    codes = schema["codes"]
    for key, mine in [
        ("role", messages.ROLES),
        ("control_command", messages.CONTROL_COMMANDS),
        ("status_event", messages.STATUS_EVENTS),
        ("rejection", messages.REJECTIONS),
        ("plan_status", messages.PLAN_STATUSES),
        ("command_mode", messages.COMMAND_MODES),
        ("intervention", messages.INTERVENTIONS),
        ("route_status", messages.ROUTE_STATUSES),
        ("replan_reason", messages.REPLAN_REASONS),
        ("route_switch", messages.ROUTE_SWITCHES),
        ("output_slot", messages.OUTPUT_SLOTS),
    ]:
        if codes[key] != mine:
            problems.append(f"codes.{key}: Rust {codes[key]}, Python {mine}")
    constants = {
        "max_horizon": messages.MAX_HORIZON,
        "route_capacity": messages.ROUTE_CAPACITY,
        "switch_unscheduled": messages.SWITCH_UNSCHEDULED,
        "no_producer": messages.NO_PRODUCER,
        "plan_missing": messages.PLAN_MISSING,
        "role_count": messages.ROLE_COUNT,
    }
    if codes["constant"] != constants:
        problems.append(f"constants: Rust {codes['constant']}, Python {constants}")
    for p in problems:
        print(p)
    print(f"{len(rust_types)} types, {len(topics)} services compared")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
