"""The companion's MAVLink 2 signing: sign everything sent, accept only the vehicle's signed
messages, and say clearly when keys do not match.

With ``companion.link.signing_key_file`` (``col fly --signing-key FILE``) every packet the link
sends (HEARTBEAT, commands, setpoints) is signed, and only messages signed with the same key
are read; the tlog records the signed packets as they went over the wire. The timestamps follow
the wall clock (:mod:`colcommon.signing`), so a restarted companion is not taken for a replay.
"""

from __future__ import annotations

from typing import Any

from colcommon.signing import make_signing, read_key

__all__ = ["diagnose", "enable_signing", "load_key", "read_key"]
from companion.config import LinkConfig

COMPANION_LINK_ID = 1


def load_key(cfg: LinkConfig) -> bytes | None:
    """The configured key, or None when signing is off; ConfigError for a bad file."""
    return read_key(cfg.signing_key_file) if cfg.signing_key_file else None


def enable_signing(mav: Any, key: bytes | None) -> None:
    """Give a pymavlink codec our signing state. Without a key nothing is checked, but signed
    packets are still counted (``sig_count``), which :func:`diagnose` uses."""
    mav.signing = make_signing(key, COMPANION_LINK_ID, allow_unsigned=None if key is None else _refuse)


def _refuse(mav: Any, _msg_id: int) -> bool:
    return False


def diagnose(mav: Any, key_file: str) -> str | None:
    """Why nothing usable arrived, if signing explains it; else None."""
    s = mav.signing
    if s.secret_key is None:
        if s.sig_count > 0:
            return ("the vehicle signs its MAVLink messages and ignores unsigned commands and setpoints: "
                    "give the companion its key (--signing-key FILE or companion.link.signing_key_file)")
        return None
    if s.badsig_count > 0 and s.goodsig_count == 0:
        return (f"wrong MAVLink signing key: {s.badsig_count} messages from the vehicle carry signatures "
                f"that do not match the key in {key_file}; use the vehicle's key")
    if s.reject_count > s.badsig_count and s.goodsig_count == 0:
        return ("the vehicle does not sign its messages, so none can be trusted with --signing-key: give "
                "it the key (col-sitl --signing-key FILE, or SETUP_SIGNING) or fly without signing")
    return None
