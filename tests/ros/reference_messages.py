"""Reference messages with a distinct, non-default value in every field (for round trips)."""

from clutch_msgs.msg import CanFrame, ClutchEstimate, PressureCommand, RigState, TorqueRequest

TYPES = {
    "RigState": RigState,
    "ClutchEstimate": ClutchEstimate,
    "TorqueRequest": TorqueRequest,
    "PressureCommand": PressureCommand,
    "CanFrame": CanFrame,
}


def _fill(msg, seed: float):
    """Give every field of ``msg`` a distinct value derived from ``seed``."""
    msg.header.stamp.sec = 1_700_000_000
    msg.header.stamp.nanosec = 123_456_789
    msg.header.frame_id = "clutch"
    for index, (name, kind) in enumerate(msg.get_fields_and_field_types().items()):
        value = seed + index
        if name == "header":
            continue
        if kind == "double":
            setattr(msg, name, value + 0.125)
        elif kind == "boolean":
            setattr(msg, name, True)  # default is False
        elif kind == "string":
            setattr(msg, name, f"text-{name}")
        elif kind.startswith("sequence<double"):
            setattr(msg, name, [value + 0.5 * i for i in range(8 if "voltages" in name else 4)])
        elif kind in ("uint32", "uint8"):
            setattr(msg, name, (index * 37 + 5) % 200)
        elif kind == "uint8[8]":
            setattr(msg, name, [(17 * i + 3) % 256 for i in range(8)])
        else:
            raise AssertionError(f"reference message: unhandled field type {kind} of {name}")
    return msg


def make_reference(type_name: str):
    """Return the reference message of ``type_name`` (every field set)."""
    return _fill(TYPES[type_name](), seed=10.0)


def to_plain(msg):
    """Convert a message to JSON-able Python values, field by field."""
    out = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if name == "header":
            out[name] = [value.stamp.sec, value.stamp.nanosec, value.frame_id]
        elif hasattr(value, "tolist"):
            out[name] = value.tolist()
        elif isinstance(value, (list, tuple)):
            out[name] = list(value)
        else:
            out[name] = value
    return out
