"""Pictures after a run: the top view's segments and file, the HUD, and the video round trip."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.msg.pad import PadDetection
from companion.pictures.flight_plot import _segments, plot_flight
from companion.pictures.recorder import EpisodeTrack, HudFrame, TrackPoint
from companion.pictures.video import draw_hud, write_episode_video


def track(whos: str, episode: int = 0) -> EpisodeTrack:
    names = {"p": "person", "a": "policy", "h": "hold"}
    return EpisodeTrack(episode, "intervention", [TrackPoint(float(i), -float(i), 5.0, names[c]) for i, c in enumerate(whos)])


def test_segments_follow_who_flew_without_gaps() -> None:
    runs = _segments(track("aappph"))
    assert [r[0] for r in runs] == ["policy", "person", "hold"]
    assert runs[1][2] == [1.0, 2.0, 3.0, 4.0]  # starts where the policy's run ended
    assert runs[2][2] == [4.0, 5.0]


def test_flight_png_is_written(tmp_path: Path) -> None:
    path = plot_flight([track("aapp"), track("ppp", 1)], {0: ("touchdown", True), 1: ("timeout", False)},
                       (0.0, 0.0), 0.5, tmp_path / "sub" / "flight.png")
    image = cv2.imread(str(path))
    assert image is not None and image.shape[0] > 300


def hud_frame(step: int, who: str = "person", pad: PadDetection | None = None) -> HudFrame:
    image = np.full((240, 320, 3), 90, np.uint8)
    jpeg = cv2.imencode(".jpg", image)[1].tobytes()
    return HudFrame(jpeg, 3, step, "intervention", who, 4.2, -0.5, pad, (320, 240), 17)


def test_the_hud_draws_the_pad_where_it_was_detected() -> None:
    img = draw_hud(hud_frame(0, pad=PadDetection(160.0, 120.0, 20.0, False)))
    assert img.shape == (480, 640, 3)
    on_circle = img[240, 320 + 40]  # the circle's rightmost point, doubled in size
    assert on_circle[1] > 200 and on_circle[0] > 80  # the HUD's green
    plain = draw_hud(hud_frame(0))
    assert abs(int(plain[240, 360][1]) - 90) < 10  # no pad, no circle


def test_the_video_has_one_frame_per_step(tmp_path: Path) -> None:
    av = pytest.importorskip("av")
    frames = [hud_frame(i, "policy" if i < 5 else "person") for i in range(12)]
    path = write_episode_video(frames, tmp_path / "episode_003.mp4", 10.5)
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        decoded = list(container.decode(video=0))
        assert stream.codec_context.name == "h264"
    assert len(decoded) == 12 and (decoded[0].width, decoded[0].height) == (640, 480)
    with pytest.raises(ValueError, match="no frames"):
        write_episode_video([], tmp_path / "x.mp4", 10.5)


def pixels_near(image: np.ndarray, hex_colour: str, tolerance: int = 30) -> int:
    from companion.pictures.flight_cv import bgr

    return int(np.count_nonzero(np.all(np.abs(image.astype(int) - bgr(hex_colour)) <= tolerance, axis=2)))


def test_without_matplotlib_opencv_draws_flight_png(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The lean install has no matplotlib, and the README promises flight.png after every run."""
    import sys

    from companion.pictures.flight_plot import COLOURS

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib raises ImportError
    tracks = [track("aaaapppp"), EpisodeTrack(1, "demonstration", [TrackPoint(-2.0, 3.0, 5.0, "person"),
                                                                    TrackPoint(0.1, 0.1, 0.2, "person")])]
    path = plot_flight(tracks, {0: ("touchdown", False), 1: ("touchdown", True)}, (0.0, 0.0), 0.5,
                       tmp_path / "run" / "flight.png", "demo: 2 episodes from above")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imread(str(path))
    assert image is not None and image.shape == (704, 704, 3)
    assert pixels_near(image, COLOURS["policy"]) > 100 and pixels_near(image, COLOURS["person"]) > 100
    assert pixels_near(image, "#d228d0") > 100  # the pad
    assert pixels_near(image, "#2e7d32") > 10 and pixels_near(image, "#b71c1c") > 10  # both touchdowns


def test_write_pictures_keeps_each_picture_apart(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    """Without PyAV (the lean install) flight.png is still written, and the log says how to get the video."""
    import sys

    from companion.app import RunResult, write_pictures
    from companion.config import CompanionConfig
    from companion.pictures.recorder import FlightRecorder

    monkeypatch.setitem(sys.modules, "av", None)
    recorder = FlightRecorder()
    recorder.tracks.append(track("aapp"))
    recorder.frames.append(hud_frame(0))
    result = RunResult(tmp_path)
    written = write_pictures(recorder, result, CompanionConfig(), "fly demo")
    assert written == [tmp_path / "flight.png"] and (tmp_path / "flight.png").is_file()
    assert any("needs PyAV" in r.getMessage() and "'.[console]'" in r.getMessage() for r in caplog.records)
