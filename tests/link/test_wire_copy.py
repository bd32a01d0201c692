"""wire_copy gives what pack-and-parse gives, for every message of the dialect."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.wire_copy import wire_copy

INT_RANGES = {
    "int8_t": (-2**7, 2**7 - 1), "uint8_t": (0, 2**8 - 1), "int16_t": (-2**15, 2**15 - 1),
    "uint16_t": (0, 2**16 - 1), "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1),
    "int64_t": (-2**63, 2**63 - 1), "uint64_t": (0, 2**64 - 1), "uint8_t_mavlink_version": (0, 2**8 - 1),
}
SPECIAL_FLOATS = (0.0, -0.0, math.nan, math.inf, -math.inf, 1e-45, 3.4e38, 0.1, -123.456789)


def _scalar(kind: str, rng: np.random.Generator) -> object:
    if kind in ("float", "double"):
        if rng.random() < 0.3:
            return float(rng.choice(SPECIAL_FLOATS))
        return float(rng.normal(0.0, 10.0 ** rng.integers(-3, 6)))
    low, high = INT_RANGES[kind]
    return int(rng.integers(low, high, endpoint=True, dtype=np.int64 if high < 2**63 else np.uint64))


def _value(kind: str, length: int, rng: np.random.Generator) -> object:
    if kind == "char":  # a string with a NUL inside at times: the receiver cuts it there
        raw = bytes(rng.integers(1, 128, rng.integers(0, length + 1)).astype(np.uint8))
        if raw and rng.random() < 0.2:
            raw = raw[: len(raw) // 2] + b"\x00" + raw[len(raw) // 2 + 1:]
        return raw
    if length:
        return [_scalar(kind, rng) for _ in range(length)]
    return _scalar(kind, rng)


def _random_message(cls: type, rng: np.random.Generator) -> object:
    lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths))  # array_lengths: wire order
    args = [_value(kind, lengths[name], rng) for name, kind in zip(cls.fieldnames, cls.fieldtypes)]
    return cls(*args)


def _same(a: object, b: object) -> bool:
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float):
        return struct.pack("<d", a) == struct.pack("<d", b) or (math.isnan(a) and math.isnan(b))
    return type(a) is type(b) and a == b


def _through_the_wire(msg: object, sender: mavlink.MAVLink) -> object:
    received = mavlink.MAVLink(None)
    received.robust_parsing = True
    buf = msg.pack(sender)  # type: ignore[attr-defined]
    sender.seq = (sender.seq + 1) % 256
    out = received.parse_buffer(buf)
    assert out is not None and len(out) == 1
    return out[0]


@pytest.mark.parametrize("seed", range(3))
def test_every_message_of_the_dialect_arrives_as_the_parser_makes_it(seed: int) -> None:
    rng = np.random.default_rng(seed)
    wire_sender, copy_sender = (mavlink.MAVLink(None, srcSystem=7, srcComponent=191) for _ in range(2))
    wire_sender.seq = copy_sender.seq = 250  # and across the wrap of the sequence number
    checked = 0
    for cls in mavlink.mavlink_map.values():
        msg = _random_message(cls, rng)
        twin = _random_message(cls, np.random.default_rng(rng.integers(2**32)))
        for name in cls.fieldnames:  # the same values in a second object (packing keeps state)
            setattr(twin, name, getattr(msg, name))
        twin.__dict__.update({k: v for k, v in msg.__dict__.items() if k.endswith("_raw")})
        parsed = _through_the_wire(msg, wire_sender)
        copied = wire_copy(twin, copy_sender)
        assert type(copied) is type(parsed)
        for name in cls.fieldnames:
            assert _same(getattr(copied, name), getattr(parsed, name)), (cls.msgname, name)
        assert (copied.get_srcSystem(), copied.get_srcComponent(), copied.get_seq()) == \
               (parsed.get_srcSystem(), parsed.get_srcComponent(), parsed.get_seq())
        assert copied.get_signed() is False and copied.get_type() == parsed.get_type()
        checked += 1
    assert checked == len(mavlink.mavlink_map) > 200
    assert copy_sender.seq == wire_sender.seq


def test_a_float_is_rounded_to_float32_as_on_the_wire() -> None:
    sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mavlink.MAVLink_attitude_message(5, 0.1, -1e-40, math.nan, 1.0 + 1e-12, 0.0, 0.0)
    copy = wire_copy(msg, sender)
    assert copy.roll == float(np.float32(0.1)) != 0.1
    assert copy.pitch == float(np.float32(-1e-40)) and math.isnan(copy.yaw) and copy.rollspeed == 1.0
