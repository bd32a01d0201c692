"""MAVLink 2 message signing, shared by the SITL and the companion: the key file, and a
signing state whose timestamps follow the wall clock.

A signed packet carries a link id, a 48-bit timestamp (10 us units since 2015-01-01 UTC) and
the first 6 bytes of SHA-256(key + packet). The receiver refuses a signature that does not
match, a timestamp not newer than the last one of the same stream (link id, system,
component), and a new stream whose timestamp is more than a minute behind its own clock: that
is what makes a replayed packet worthless. pymavlink implements the check; pymavlink's sender
only adds 1 per packet, so after a long run its timestamps fall behind the wall clock and a
receiver that starts later would refuse them as stale. :class:`WallClockSigning` keeps them at
least at the wall clock.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from pymavlink.dialects.v20.common import MAVLinkSigning

from colcommon.errors import ConfigError

KEY_BYTES = 32
EPOCH_2015_S = 1420070400
TIMESTAMP_UNITS_PER_S = 100_000  # 10 us
NEW_STREAM_WINDOW = 6_000_000  # pymavlink's limit: a new stream at most 60 s behind our clock
AllowUnsigned = Callable[[object, int], bool]


def wall_timestamp() -> int:
    """Now in MAVLink signing units (10 us since 2015-01-01 UTC)."""
    return int((max(time.time(), EPOCH_2015_S) - EPOCH_2015_S) * TIMESTAMP_UNITS_PER_S)


def parse_key(data: bytes, source: str = "key") -> bytes:
    """A 32-byte key from 64 hex digits (spaces and newlines ignored) or 32 raw bytes."""
    text = b"".join(data.split())
    try:
        key = bytes.fromhex(text.decode("ascii"))
    except (UnicodeDecodeError, ValueError):
        key = data if len(data) == KEY_BYTES else b""
    if len(key) != KEY_BYTES:
        raise ConfigError(
            f"{source}: a MAVLink signing key is 32 bytes, written as 64 hex digits; make one "
            "with `python -c \"import secrets; print(secrets.token_hex(32))\" > signing.key`"
        )
    if key == bytes(KEY_BYTES):
        raise ConfigError(f"{source}: the all-zero key means 'signing off' in MAVLink; use a random key")
    return key


def read_key(path: str | Path) -> bytes:
    """The signing key in ``path`` (see :func:`parse_key`); ConfigError saying what to fix."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read the signing key file {p}: {exc.strerror or exc}") from None
    return parse_key(data, f"signing key file {p}")


class WallClockSigning(MAVLinkSigning):
    """pymavlink's signing state with a timestamp never behind the wall clock."""

    def __init__(self) -> None:
        self._timestamp = 0
        super().__init__()

    @property  # type: ignore[override]
    def timestamp(self) -> int:
        return max(self._timestamp, wall_timestamp())

    @timestamp.setter
    def timestamp(self, value: int) -> None:
        self._timestamp = int(value)


def make_signing(
    key: bytes | None, link_id: int = 0, allow_unsigned: AllowUnsigned | None = None
) -> WallClockSigning:
    """A signing state: with ``key``, outgoing packets are signed and incoming ones checked
    (unsigned ones pass only if ``allow_unsigned(mav, msg_id)`` says so); without, it is off."""
    s = WallClockSigning()
    set_key(s, key)
    s.link_id = link_id
    s.allow_unsigned_callback = allow_unsigned
    return s


def set_key(s: MAVLinkSigning, key: bytes | None) -> None:
    """Switch signing on with ``key`` (None: off). Streams seen so far stay remembered."""
    s.secret_key = key
    s.sign_outgoing = key is not None
