"""Who may reach the SITL: loopback by default; anything wider is explicit and, for the
control surface (episode resets, teleporting the world), guarded by a token.

The SITL's MAVLink ports, camera stream and control surface all bind ``network.host``. A host
other than a loopback address needs ``--allow-remote``, and then a control token: every
control request must carry ``"token": "..."`` (compared in constant time). MAVLink over the
network is protected by signing (``--signing-key``), not by this module.
"""

from __future__ import annotations

import hmac
import json

from colcommon.errors import ConfigError
from colcommon.network import is_loopback

MIN_TOKEN_CHARS = 16


def check_exposure(host: str, allow_remote: bool, control_token: str | None) -> None:
    """ConfigError unless binding ``host`` is loopback, or explicitly allowed with a token."""
    if is_loopback(host):
        return
    if not allow_remote:
        raise ConfigError(
            f"the SITL would listen on {host!r}, reachable from other machines: its control surface "
            "resets episodes and moves the world. Bind 127.0.0.1, or pass --allow-remote together "
            "with --control-token-file FILE (and --signing-key for MAVLink)"
        )
    if not control_token or len(control_token) < MIN_TOKEN_CHARS:
        raise ConfigError(
            f"--allow-remote on {host!r} needs a control token of at least {MIN_TOKEN_CHARS} characters "
            "(--control-token-file FILE); clients send it as \"token\" in every control request"
        )


def authorised(line: bytes, token: str | None) -> bool:
    """Does this control request carry the token (always True when none is set)?"""
    if not token:
        return True
    try:
        given = json.loads(line.decode("utf-8")).get("token")
    except (UnicodeDecodeError, ValueError, AttributeError, RecursionError):
        return False
    return isinstance(given, str) and hmac.compare_digest(given.encode(), token.encode())
