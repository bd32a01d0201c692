"""What a MAVLink message becomes on the other end of the wire, without the wire.

A message sent by one pymavlink codec and parsed by another comes out with every ``float``
rounded to float32, every string cut at its first NUL byte and its arrays as lists, with the
sender's system, component and sequence number in its header. :func:`wire_copy` makes that
message from the payload alone: the same packing as on the wire, the same unpacking as
pymavlink's decoder, but no framing, no checksum (two pure-Python CRC passes were most of a
message's cost) and no byte-by-byte parser. The in-process SITL hands its messages over this
way (:mod:`companion.inprocess`); ``tests/link/test_wire_copy.py`` checks it against
the real pack-and-parse for every message either side sends.

Signed messages cannot be copied like this (the signature covers the framed bytes): callers use
the wire when signing is on.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink


def _payload_only(mav: Any, crc_extra: int, payload: bytes, force_mavlink1: bool = False) -> bytes:
    return payload


def payload(msg: Any) -> bytes:
    """The message's packed payload (untruncated), as its ``pack`` builds it for the wire."""
    msg._pack = _payload_only  # the instance's own attribute shadows the framing method for one call
    try:
        return bytes(msg.pack(None))
    finally:
        del msg._pack


def _fields(cls: Any, values: tuple[Any, ...]) -> list[Any]:
    """Unpacked struct values in the constructor's order, as pymavlink's ``decode`` orders them."""
    order_map, len_map = cls.orders, cls.lengths
    if sum(len_map) == len(len_map):
        fields = [values[order_map[i]] for i in range(len(values))]
    else:
        fields = []
        for order in order_map:
            length = len_map[order]
            tip = sum(len_map[:order])
            field = values[tip]
            fields.append(field if length == 1 or isinstance(field, bytes) else list(values[tip:tip + length]))
    return [f.rstrip(b"\x00") if isinstance(f, bytes) else f for f in fields]


def wire_copy(msg: Any, sender: Any) -> Any:
    """``msg`` as a parser receives it from ``sender`` (a pymavlink ``MAVLink`` codec), whose
    sequence number advances as :meth:`send` advances it."""
    cls = type(msg)
    body = payload(msg)
    copy = cls(*_fields(cls, cls.unpacker.unpack(body)))
    mlen = len(body.rstrip(b"\x00")) or 1  # MAVLink 2 drops trailing zero bytes (at least one stays)
    copy._header = mavlink.MAVLink_header(cls.id, 0, 0, mlen, sender.seq, sender.srcSystem, sender.srcComponent)
    copy._payload = body[:mlen]
    copy._signed = False
    sender.seq = (sender.seq + 1) % 256
    sender.total_packets_sent += 1
    return copy
