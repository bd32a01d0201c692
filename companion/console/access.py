"""Who may use the console: this machine by default; anyone else only when asked, with a token.

The console flies a vehicle, so two doors are shut:

- **Binding.** The page is served on 127.0.0.1 unless ``--host`` says otherwise; any other
  address needs ``--allow-remote`` and a token (``--token-file``) that the page and the socket
  must carry (``?token=...``, compared in constant time).
- **Cross-site WebSocket hijacking.** Any web page the person has open could open a socket to
  ``ws://127.0.0.1:PORT/ws`` and fly the vehicle. Browsers send an ``Origin`` header with every
  WebSocket handshake, so the socket accepts only its own origin (the scheme, host and port the
  page was served from) and refuses every other one.
"""

from __future__ import annotations

import hmac
from urllib.parse import urlsplit

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


def origin_ok(origin: str | None, host_header: str | None) -> bool:
    """Is a WebSocket handshake from the console's own page?

    A browser always sends ``Origin``; it must name the host and port the request was sent to
    (``Host``). A client that is not a browser sends none and is let through: it could forge
    the header anyway, and what keeps it out is the loopback binding or the token."""
    if origin is None:
        return True
    if host_header is None:
        return False
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host_header.lower()
