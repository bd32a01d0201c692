"""Who may use the console: this machine by default; anyone else only when asked, with a token.

The console flies a vehicle, so two doors are shut:

- **Binding.** The page is served on 127.0.0.1 unless ``--host`` says otherwise; any other
  address needs ``--allow-remote`` and a token (``--token-file``) that the page and the socket
  must carry (``?token=...``, compared in constant time).
- **Cross-site WebSocket hijacking.** Any web page the person has open could open a socket to
  ``ws://127.0.0.1:PORT/ws`` and fly the vehicle. Browsers send an ``Origin`` header with every
  WebSocket handshake, so the socket accepts only its own origin (exactly ``http://`` and the
  host and port the page was served from; an ``Origin`` header sent twice is refused) and
  refuses every other one.
- **DNS rebinding.** A name the attacker controls can resolve to 127.0.0.1; its page is then
  "same origin" with the console (Origin and Host both say ``attacker.example:PORT``). So every
  request's ``Host`` must be a name the console answers to: the loopback names, and with
  ``--allow-remote`` the configured host and ``--allow-host`` names (:func:`allowed_hosts`).
"""

from __future__ import annotations

import hmac
import ipaddress
import socket
from collections.abc import Sequence

from colcommon.network import is_loopback
from companion.errors import ConfigError

MIN_TOKEN_CHARS = 16


def check_console_exposure(host: str, allow_remote: bool, token: str | None) -> None:
    """ConfigError unless ``host`` is loopback, or other machines are allowed with a token."""
    if is_loopback(host):
        return
    if not allow_remote:
        raise ConfigError(
            f"the console would listen on {host!r}, reachable from other machines, and it flies the "
            "vehicle. Serve it on 127.0.0.1, or pass --allow-remote together with --token-file FILE")
    if not token or len(token) < MIN_TOKEN_CHARS:
        raise ConfigError(f"--allow-remote on {host!r} needs a token of at least {MIN_TOKEN_CHARS} "
                          "characters (--token-file FILE); open the page as http://HOST:PORT/?token=...")


def token_ok(given: str | None, token: str | None) -> bool:
    """Does a request carry the token (always True when none is set)?"""
    if not token:
        return True
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def origin_ok(origin: str | Sequence[str] | None, host_header: str | None) -> bool:
    """Is a WebSocket handshake from the console's own page?

    ``origin``: the request's ``Origin`` header, or every value of it (a header sent twice is
    refused, whatever its first value). A browser always sends one ``Origin``; it must be exactly
    the console's own: ``http`` (the console serves plain HTTP, so ``https://`` is another
    origin), and the host and port the request was sent to (``Host``), nothing more. A client
    that is not a browser sends none and is let through: it could forge the header anyway, and
    what keeps it out is the loopback binding or the token."""
    values = [] if origin is None else [origin] if isinstance(origin, str) else list(origin)
    if not values:
        return True
    if len(values) != 1 or not host_header:
        return False
    return values[0].lower() == f"http://{host_header.lower()}"


LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
WILDCARDS = frozenset({"0.0.0.0", "::", ""})


def allowed_hosts(host: str, allow_remote: bool, extra: tuple[str, ...] = ()) -> frozenset[str]:
    """The names a request's ``Host`` may carry (without port, lower case).

    Loopback names always; with ``allow_remote`` also ``host`` itself and ``extra`` (the names
    other machines use); a wildcard bind without ``extra`` answers to this machine's own name."""
    names = set(LOOPBACK_NAMES)
    if allow_remote:
        names.update(n.lower() for n in extra)
        if host.lower() not in WILDCARDS:
            names.add(host.lower())
        elif not extra:
            names.update({socket.gethostname().lower(), socket.getfqdn().lower()})
    return frozenset(names)


def host_name(host_header: str) -> str | None:
    """The name of a ``Host`` header without its port (``[::1]:8765`` -> ``::1``); None if malformed."""
    value = host_header.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        if end < 0 or (value[end + 1:] and not value[end + 1:].startswith(":")):
            return None
        return value[1:end]
    name, _, port = value.partition(":")
    if port and not port.isdigit():
        return None
    return name or None


def host_ok(host_header: str | None, allowed: frozenset[str]) -> bool:
    """Is the request addressed to a name this console answers to (no DNS rebinding)?"""
    if host_header is None:
        return False
    name = host_name(host_header)
    if name is None:
        return False
    if name in allowed:
        return True
    try:  # 127.0.0.2 etc.: loopback addresses by number cannot be rebound
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def page_url(host: str, port: int, allowed: frozenset[str]) -> str:
    """The address to print: a wildcard bind is shown as a name other machines can use."""
    shown = host
    if host.lower() in WILDCARDS:
        names = sorted(allowed - LOOPBACK_NAMES)
        shown = names[0] if names else "127.0.0.1"
    if ":" in shown:
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/"
