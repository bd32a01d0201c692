"""The gaps of an episode (companion/control/gaps.py): what is counted, logged and told to the
operator as a gap starts, changes and ends."""

from __future__ import annotations

import logging

import pytest

from companion.control.gaps import LINK_LOST, STALE_TELEMETRY, VIDEO_MISSING, Gap, GapReporter


class Watcher:
    def __init__(self) -> None:
        self.told: list[str | None] = []

    def on_gap(self, gap: Gap | None) -> None:
        self.told.append(None if gap is None else gap.kind)


def test_the_watcher_is_told_each_change_and_the_log_each_start(caplog: pytest.LogCaptureFixture) -> None:
    watcher = Watcher()
    gaps = GapReporter(lambda: watcher)
    gaps.begin()
    with caplog.at_level(logging.WARNING, logger="companion.control.gaps"):
        for gap in (None, STALE_TELEMETRY, STALE_TELEMETRY, None, VIDEO_MISSING, LINK_LOST, LINK_LOST, None):
            gaps.note(gap)
    assert watcher.told == ["telemetry", None, "video", "link", None]
    assert [r.getMessage() for r in caplog.records] == [STALE_TELEMETRY.text, VIDEO_MISSING.text, LINK_LOST.text]
    assert gaps.notes() == ["2 steps held on stale telemetry, not recorded",
                            "vehicle link lost 1 times, nothing recorded meanwhile",
                            "1 steps flown without a camera frame, not recorded"]


def test_a_new_episode_counts_afresh_and_ends_a_gap_left_over() -> None:
    watcher = Watcher()
    gaps = GapReporter(lambda: watcher)
    gaps.begin()
    assert watcher.told == []  # nothing was going on
    gaps.note(STALE_TELEMETRY)
    gaps.begin()
    assert watcher.told == ["telemetry", None] and gaps.notes() == []


def test_nobody_watching_is_fine_and_a_watcher_set_later_is_told() -> None:
    watcher: Watcher | None = None
    gaps = GapReporter(lambda: watcher)
    gaps.note(VIDEO_MISSING)
    watcher = Watcher()
    gaps.note(None)
    assert watcher.told == [None]
