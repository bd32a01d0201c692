"""Connection strings as MAVLink tools spell them, turned into pymavlink's arguments.

Accepted: ``udpin:HOST:PORT`` (listen), ``udpout:HOST:PORT`` (send first), ``udp:HOST:PORT``
(as MAVProxy: listen), ``tcp:HOST:PORT`` (client), ``tcpin:HOST:PORT`` (server), and a serial
device with an optional baud rate: ``/dev/ttyACM0``, ``/dev/ttyACM0,57600``,
``/dev/ttyUSB0:921600``, ``serial:/dev/ttyUSB0:57600``, ``COM3``. MAVSDK's spelling of the same
(``udpin://0.0.0.0:14540``, ``serial:///dev/ttyUSB0:57600``) is accepted too; anything else is a
clear :class:`ConfigError` naming these forms, before a socket or a device is touched.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from companion.errors import ConfigError, LinkError

NETWORK_SCHEMES = ("udpin", "udpout", "udp", "tcp", "tcpin")
DEFAULT_BAUD = 57600
ACCEPTED = ("udpin:HOST:PORT, udpout:HOST:PORT, udp:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT or a serial "
            "device (/dev/ttyACM0,57600, serial:/dev/ttyUSB0:57600, COM3)")


@dataclass(frozen=True)
class ConnectionSpec:
    """A parsed connection string: what pymavlink's ``mavlink_connection`` is given."""

    kind: str  # one of NETWORK_SCHEMES or "serial"
    device: str  # pymavlink device string (scheme:host:port, or a serial device path)
    baud: int = DEFAULT_BAUD

    @property
    def is_network(self) -> bool:
        return self.kind != "serial"


def _network(scheme: str, rest: str, original: str) -> ConnectionSpec:
    host, _, port = rest.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(
            f"connection {original!r}: expected {scheme}:HOST:PORT with a port in 1..65535, "
            f"e.g. {scheme}:127.0.0.1:14540"
        )
    if scheme == "udp":  # MAVProxy's meaning of a bare udp: listen on it
        scheme = "udpin"
    return ConnectionSpec(scheme, f"{scheme}:{host}:{port}")


def _serial(rest: str, original: str) -> ConnectionSpec:
    match = re.fullmatch(r"(.+?)(?:[,:](\d+))?", rest)
    if match is None or not match.group(1):
        raise ConfigError(
            f"connection {original!r}: expected a serial device such as /dev/ttyUSB0,57600"
        )
    baud = int(match.group(2)) if match.group(2) else DEFAULT_BAUD
    if baud <= 0:
        raise ConfigError(f"connection {original!r}: baud rate must be positive")
    return ConnectionSpec("serial", match.group(1), baud)


def parse_connection(text: str, baud: int | None = None) -> ConnectionSpec:
    """Parse ``text``; ``baud`` (if given) overrides a serial device's default rate."""
    text = text.strip()
    if not text:
        raise ConfigError(
            "empty connection string; use e.g. udpin:0.0.0.0:14540 or /dev/ttyACM0,57600"
        )
    scheme, sep, rest = text.partition(":")
    scheme = scheme.lower()
    if sep and rest.startswith("//") and scheme in (*NETWORK_SCHEMES, "serial"):
        rest = rest[2:]  # MAVSDK's URL spelling of the same connection
    if sep and scheme in NETWORK_SCHEMES:
        return _network(scheme, rest, text)
    if sep and scheme == "serial":
        spec = _serial(rest, text)
    elif _is_device(text):
        spec = _serial(text, text)
    else:  # bogus://x or a misspelt scheme: not a device pymavlink should try to open
        what = f"unknown scheme {scheme!r}" if sep else "not a connection string"
        raise ConfigError(f"connection {text!r}: {what}; use {ACCEPTED}")
    if baud is not None and not re.search(r"[,:]\d+$", text):
        spec = ConnectionSpec("serial", spec.device, baud)
    return spec


def _is_device(text: str) -> bool:
    """A serial device as the systems name them: a path (``/dev/ttyACM0``, ``./pty``) or ``COMn``."""
    return text.startswith(("/", ".")) or re.match(r"com\d+", text, re.IGNORECASE) is not None


def open_mavlink(spec: ConnectionSpec, source_system: int, source_component: int) -> Any:
    """A pymavlink connection for ``spec`` that speaks MAVLink 2 from its first packet.

    pymavlink starts in MAVLink 1 unless a process-wide environment variable says otherwise;
    instead of touching the environment, this connection gets its own MAVLink 2 codec.
    """
    from pymavlink import mavutil
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    try:
        conn = mavutil.mavlink_connection(
            spec.device,
            baud=spec.baud,
            source_system=source_system,
            source_component=source_component,
            autoreconnect=spec.kind in ("tcp", "serial"),
        )
    except (OSError, ValueError) as exc:
        advice = ("Check that the address is one of this machine's and the port is free (another "
                  "ground station?)" if spec.is_network else
                  "Check that the device exists and that you may open it (the dialout group)")
        raise LinkError(f"cannot open MAVLink connection {spec.device!r}: {exc}. {advice}") from exc
    conn.mav = dialect.MAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False
    return conn
