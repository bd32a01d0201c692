"""Watches a run step by step (as its RunControl) and keeps what the pictures need: every
episode's track, who flew each step, and the last episode's camera frames (JPEG in memory)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from companion.control.arbiter import Phase
from companion.control.records import StepView
from companion.msg.pad import PadDetection


@dataclass(frozen=True)
class TrackPoint:
    north_m: float
    east_m: float
    altitude_m: float
    who: str  # person | policy | hold


@dataclass(frozen=True)
class HudFrame:
    """One step of the last episode: its camera image (JPEG) and what the HUD shows."""

    jpeg: bytes
    episode: int
    step: int
    phase: str
    who: str
    altitude_m: float
    climb_m_s: float
    pad: PadDetection | None
    image_size_px: tuple[int, int]
    policy_version: int | None


@dataclass
class EpisodeTrack:
    episode: int
    phase: str
    points: list[TrackPoint] = field(default_factory=list)


def who_flew(view: StepView) -> str:
    if view.decision.source == "human":
        return "hold" if view.human_hold else "person"
    return "policy"


class FlightRecorder:
    """A RunControl that only watches: never pauses, never ends an episode."""

    def __init__(self, video: bool = True, jpeg_quality: int = 85) -> None:
        self.video, self.jpeg_quality = video, jpeg_quality
        self.tracks: list[EpisodeTrack] = []
        self.frames: list[HudFrame] = []
        self._camera: Any = None

    def started(self, vehicle: Any, learner: Any, dataset: Any) -> None:
        self._camera = vehicle.camera if self.video else None

    def before_episode(self, episode: int, phase: Phase) -> bool:
        self.tracks.append(EpisodeTrack(episode, phase.value))
        self.frames = []  # only the last episode's video is kept
        return True

    def end_requested(self) -> str | None:
        return None

    def on_gap(self, gap: Any) -> None:
        """Gaps are in the episode's record; the pictures show the steps as flown."""

    def on_step(self, view: StepView) -> None:
        obs, who = view.observation, who_flew(view)
        n, e, d = obs.position_ned_m
        if self.tracks:
            self.tracks[-1].points.append(TrackPoint(n, e, -d, who))
        if self._camera is None:
            return
        frame = self._camera.latest()
        if frame is None:
            image = np.zeros((obs.image_size_px[1], obs.image_size_px[0], 3), np.uint8)
        else:
            image = frame.image
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if ok:
            self.frames.append(HudFrame(buf.tobytes(), view.episode, view.step, view.phase.value, who, -d,
                                        -obs.velocity_ned_m_s[2], obs.pad, obs.image_size_px, view.policy_version))
