"""Why a control step is not a true sample: the vehicle-side gaps in an episode.

A sample is the person's command paired with the vehicle's state at that step. When the state
is not the vehicle's at that step, the pair is a false label and trains the policy wrong, so
nothing is recorded:

- ``telemetry``: the position, velocity or attitude the observation is made of is no newer, by
  the vehicle's own stamp of each message, than the previous step's (a starved or frozen
  autopilot, a stalled link). The step sends the zero-velocity hold.
- ``link``: nothing heard for ``link_lost_s``: the companion stops streaming and the vehicle's
  own failsafe holds, until the link is back (or ``link_patience_s`` runs out).
- ``video``: the configured camera gave no usable frame for the step: the pad's state is
  unknown (not "not visible"). The step flies as decided, but is not recorded.

The episode loop notes each step's gap in a :class:`GapReporter`, which logs a gap as it starts,
tells a :class:`GapWatcher` (the console) when a gap starts, changes or ends, and gives the count
of each kind for the episode's record.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

log = logging.getLogger(__name__)

GapKind = Literal["telemetry", "link", "video"]
GAP_KINDS: tuple[GapKind, ...] = ("telemetry", "link", "video")


@dataclass(frozen=True)
class Gap:
    """One reason the steps are not being recorded (and, but for ``video``, the vehicle holds)."""

    kind: GapKind
    text: str

    @property
    def holding(self) -> bool:
        """The vehicle holds position (telemetry, link) or flies on, unrecorded (video)."""
        return self.kind != "video"


STALE_TELEMETRY = Gap("telemetry", "the vehicle's telemetry is stale (no newer position, velocity or attitude "
                                   "since the last step): holding position, nothing recorded")
LINK_LOST = Gap("link", "the vehicle's MAVLink link is lost: not streaming, the vehicle's failsafe holds; "
                        "nothing recorded until it is back")
VIDEO_MISSING = Gap("video", "the camera gave no frame for this step: the pad's state is unknown; "
                             "steps fly on but are not recorded")


class GapCounter:
    """Counts an episode's gap steps by kind, and says when the current gap changes."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self.current: Gap | None = None

    def reset(self) -> None:
        self.counts = Counter()

    def step(self, gap: Gap | None, count: bool = True) -> bool:
        """Note one step's gap (None: a whole step; a link loss counts once per loss); True when
        it differs from the last step's. ``count=False``: only set the current gap."""
        if gap is not None and count and (gap.kind != "link" or gap != self.current):
            self.counts[gap.kind] += 1
        changed = gap != self.current
        self.current = gap
        return changed

    def notes(self) -> list[str]:
        """The episode's record notes: one per kind that occurred."""
        words = {"telemetry": "{n} steps held on stale telemetry, not recorded",
                 "link": "vehicle link lost {n} times, nothing recorded meanwhile",
                 "video": "{n} steps flown without a camera frame, not recorded"}
        return [words[k].format(n=self.counts[k]) for k in GAP_KINDS if self.counts[k]]


class GapWatcher(Protocol):
    """Someone told when the steps stop being recordable for a vehicle-side reason, or are whole
    again (None): the console (:class:`~companion.control.session.EpisodeControl`)."""

    def on_gap(self, gap: Gap | None) -> None: ...


class GapReporter:
    """One vehicle's gaps, episode by episode: counted, logged as each starts, and told to the
    watcher ``watcher()`` gives (read at each change: a run may swap it; None: nobody watches)."""

    def __init__(self, watcher: Callable[[], GapWatcher | None]) -> None:
        self.counter = GapCounter()
        self.watcher = watcher

    def begin(self) -> None:
        """A new episode: its own counts, and a gap left over from the last episode is over."""
        self.counter.reset()
        if self.counter.step(None, count=False):
            self._tell(None)

    def note(self, gap: Gap | None) -> None:
        """This step's gap (None: a whole step); the watcher is told when it changes."""
        if self.counter.step(gap):
            if gap is not None:
                log.warning("%s", gap.text)
            self._tell(gap)

    def notes(self) -> list[str]:
        return self.counter.notes()

    def _tell(self, gap: Gap | None) -> None:
        watcher = self.watcher()
        if watcher is not None:
            watcher.on_gap(gap)
