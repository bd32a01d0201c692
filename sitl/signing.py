"""The vehicle's MAVLink 2 signing: one key and one signing state for every link.

With a key (``col-sitl --signing-key FILE``, or SETUP_SIGNING) the vehicle signs everything
it sends and obeys only messages signed with that key, as PX4 does with signing required:
unsigned or wrongly signed commands, setpoints, MANUAL_CONTROL and parameter writes are
dropped by the parser (counted, never applied). Unsigned HEARTBEAT and RADIO_STATUS still pass,
so a ground station without the key still sees the vehicle (its telemetry is signed; a
receiver without the key reads it unchecked). Replays are refused by timestamp (see
:mod:`colcommon.signing`). All links share one state, so a replay on another link, or after a
parser reset, is refused too.

SETUP_SIGNING: accepted when signed with the current key (a new key; the all-zero key with
timestamp 0 switches signing off), or, while the vehicle has no key, over a TCP connection:
the SITL's stand-in for PX4's USB link, the "secure first link". The key lives in memory.
"""

from __future__ import annotations

import logging
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from colcommon.signing import KEY_BYTES, make_signing, set_key

log = logging.getLogger("sitl.signing")
M = mavlink
UNSIGNED_ALLOWED = frozenset({M.MAVLINK_MSG_ID_HEARTBEAT, M.MAVLINK_MSG_ID_RADIO_STATUS})


class SitlSigning:
    """The SITL's signing state, its policy for unsigned messages and SETUP_SIGNING."""

    def __init__(self, key: bytes | None = None, system_id: int = 1) -> None:
        self.system_id = system_id
        self.state = make_signing(key, link_id=0, allow_unsigned=self._allow_unsigned)
        self.setups_refused = 0

    @property
    def required(self) -> bool:
        return self.state.secret_key is not None

    @staticmethod
    def _allow_unsigned(_mav: Any, msg_id: int) -> bool:
        return msg_id in UNSIGNED_ALLOWED

    def attach(self, mav: mavlink.MAVLink) -> mavlink.MAVLink:
        """Give a parser or encoder the shared state (so sending signs and parsing checks)."""
        mav.signing = self.state
        return mav

    def rejected(self) -> int:
        """Messages refused so far: unsigned, wrongly signed or replayed."""
        return int(self.state.reject_count)

    def on_setup_signing(self, msg: mavlink.MAVLink_message, secure_link: bool) -> bool:
        """Apply a SETUP_SIGNING addressed to us if its link may; True when applied."""
        if msg.target_system not in (0, self.system_id):
            return False
        may = msg.get_signed() if self.required else secure_link
        if not may:
            self.setups_refused += 1
            log.warning("SETUP_SIGNING refused: %s", "not signed with the current key" if self.required
                        else "without a key, only over a TCP (wired) link")
            return False
        key = bytes(msg.secret_key)[:KEY_BYTES]
        if key == bytes(KEY_BYTES) and msg.initial_timestamp == 0:
            set_key(self.state, None)
            log.warning("MAVLink signing switched off by SETUP_SIGNING")
            return True
        set_key(self.state, key)
        self.state.timestamp = max(self.state.timestamp, int(msg.initial_timestamp))
        log.warning("MAVLink signing key set by SETUP_SIGNING: signed messages required")
        return True
