"""Who holds the console's pilot role, and the seat kept for a pilot whose link dropped.

Why: a page's socket can drop for a moment (Wi-Fi, a suspended laptop lid, a busy machine missing
a WebSocket ping) while the person is still at the sticks. Without a seat kept for them, the page
comes back as a watcher and the person must notice and ask again; with one, the same tab (the
``tab`` key it keeps in its session storage and sends with the socket) is the pilot again when its
link returns within ``grace_s``. The seat never locks anyone out: while it is kept, any other page
may still take the role (someone must be able to intervene), and then the seat is gone.
Safety does not depend on it: while the pilot's link is down its input is silent and the vehicle
holds (:class:`~companion.inputs.browser.BrowserInput`), seat or no seat.

Pure logic with an injected clock; the server (:mod:`companion.console.server`) does the I/O.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass

GRACE_S = 15.0
"""How long the role waits for a pilot's page whose link dropped."""

_TAB_KEY = re.compile(r"[0-9a-f]{16,64}")


def tab_key(raw: str | None) -> str | None:
    """The page's tab key from its socket URL (``?tab=``), or None when absent or malformed
    (such a page gets no seat kept for it, nothing else changes)."""
    if raw is None or not _TAB_KEY.fullmatch(raw):
        return None
    return raw


@dataclass
class _Seat:
    tab: str
    page: int
    until_s: float


class PilotSeat:
    """The seat kept for the last pilot whose link dropped (at most one)."""

    def __init__(self, grace_s: float = GRACE_S, clock: Callable[[], float] = time.monotonic) -> None:
        if not grace_s >= 0.0:
            raise ValueError(f"the pilot's grace must be >= 0 s, got {grace_s}")
        self.grace_s = grace_s
        self._clock = clock
        self._seat: _Seat | None = None

    def keep_for(self, tab: str | None, page: int) -> bool:
        """The pilot's page ``page`` lost its link: keep the role for its tab; False when it has
        no tab key (nothing kept)."""
        self._seat = None if tab is None or self.grace_s == 0.0 else _Seat(tab, page, self._clock() + self.grace_s)
        return self._seat is not None

    def returns(self, tab: str | None) -> int | None:
        """A page connected with ``tab``: the page number it had as pilot if the seat was kept
        for it and the grace has not run out (the seat is then used up), else None."""
        seat = self._seat
        if seat is None or tab is None or seat.tab != tab:
            return None
        self._seat = None
        return seat.page if self._clock() <= seat.until_s else None

    def release(self) -> None:
        """Another page took the role (or the pilot gave it up): no seat is kept."""
        self._seat = None

    @property
    def kept_for(self) -> int | None:
        """The page whose seat is kept now, or None."""
        seat = self._seat
        return seat.page if seat is not None and self._clock() <= seat.until_s else None
