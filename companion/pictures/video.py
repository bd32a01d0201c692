"""``episode_NNN.mp4``: the last episode's camera with the HUD drawn in (H.264 through PyAV).

The HUD is the console's: altitude, vertical speed, who flies, episode/phase/step, policy
version, and the detected pad (circle and centre)."""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from companion.pictures.recorder import HudFrame

BGR = {"person": (0, 152, 255), "policy": (246, 182, 41), "hold": (53, 57, 229)}
SCALE = 2  # 320x240 -> 640x480


def _text(img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int] = (255, 255, 255),
          size: float = 0.55) -> None:
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, size, 1)
    x, y = org
    cv2.rectangle(img, (x - 3, y - h - 4), (x + w + 3, y + base), (0, 0, 0), -1)
    cv2.putText(img, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)


def draw_hud(frame: HudFrame) -> np.ndarray:
    """The frame's image, doubled in size, with the HUD."""
    image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"the camera image of step {frame.step} cannot be decoded")
    img = cv2.resize(image, (image.shape[1] * SCALE, image.shape[0] * SCALE), interpolation=cv2.INTER_LINEAR)
    k = img.shape[1] / frame.image_size_px[0]
    if frame.pad is not None:
        c = (int(round(frame.pad.u_px * k)), int(round(frame.pad.v_px * k)))
        colour = (59, 235, 255) if frame.pad.partial else (118, 230, 0)
        cv2.circle(img, c, max(1, int(round(frame.pad.radius_px * k))), colour, 2, cv2.LINE_AA)
        cv2.drawMarker(img, c, colour, cv2.MARKER_CROSS, 14, 2)
    _text(img, f"ALT {frame.altitude_m:5.2f} m", (10, 24))
    _text(img, f"VS {frame.climb_m_s:+5.2f} m/s", (10, 48))
    who = {"person": "PERSON FLIES", "policy": "POLICY FLIES", "hold": "HOLDING"}[frame.who]
    (w, _), _ = cv2.getTextSize(who, cv2.FONT_HERSHEY_SIMPLEX, 0.8, 2)
    _text(img, who, (img.shape[1] - w - 14, 28), BGR[frame.who], 0.8)
    version = "-" if frame.policy_version is None else str(frame.policy_version)
    _text(img, f"episode {frame.episode}  {frame.phase}  step {frame.step}", (10, img.shape[0] - 36))
    _text(img, f"policy v{version}", (10, img.shape[0] - 12))
    return img


def write_episode_video(frames: Sequence[HudFrame], path: Path, fps: float) -> Path:
    """Encode the frames with their HUD as H.264 in an MP4 (yuv420p: plays everywhere)."""
    import av

    if not frames:
        raise ValueError("no frames to write")
    path.parent.mkdir(parents=True, exist_ok=True)
    first = draw_hud(frames[0])
    rate = Fraction(fps).limit_denominator(1000)
    with av.open(str(path), mode="w") as container:
        stream = container.add_stream("libx264", rate=rate)
        stream.width, stream.height, stream.pix_fmt = first.shape[1], first.shape[0], "yuv420p"
        stream.options = {"preset": "veryfast", "crf": "23"}
        for i, f in enumerate(frames):
            img = first if i == 0 else draw_hud(f)
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path
