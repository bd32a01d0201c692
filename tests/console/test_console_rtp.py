"""``col console --rtp HOST:PORT``: the frames the page gets also go out as H.264 over RTP, and a
real decoder (FFmpeg through PyAV) reads them back; a bad destination is refused at once."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from colcommon.frames import Frame
from companion.config import CompanionConfig
from companion.console.session import ConsoleOptions, ConsoleSession
from sitl.rtp import sdp_for
from tests.conftest import free_port
from tests.console import REPO
from tests.sitl.test_rtp_video import receive

pytestmark = [pytest.mark.realtime, pytest.mark.timeout(120)]
av = pytest.importorskip("av")


def test_the_consoles_frames_go_out_over_rtp(tmp_path: Path) -> None:
    port = free_port()
    sdp = tmp_path / "console.sdp"
    sdp.write_text(sdp_for("127.0.0.1", port))
    session = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=tmp_path / "run", rtp=f"127.0.0.1:{port}"),
                             lambda m: None, lambda b: None)
    frames: list[np.ndarray] = []
    stop = threading.Event()
    reader = threading.Thread(target=receive, args=(sdp, frames, stop, 3), daemon=True)
    reader.start()
    image = np.zeros((240, 320, 3), np.uint8)
    image[:, 160:] = 255  # right half white
    try:
        for n in range(600):  # until the decoder has three pictures (it joins at a key frame)
            session._on_frame(Frame(n, 28 * n, image), b"")
            reader.join(0.03)
            if not reader.is_alive():
                break
    finally:
        stop.set()
        if session._rtp is not None:
            session._rtp.close()
    assert len(frames) >= 3, "no H.264 pictures decoded from the console's RTP stream"
    assert frames[-1].shape == (240, 320, 3)
    assert frames[-1][:, :150].mean() < 40 and frames[-1][:, 170:].mean() > 215


def test_a_bad_rtp_destination_is_refused_before_anything_starts(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "companion.cli", "console", "--rtp", "5600", "--port", "0",
                           "--run-dir", str(tmp_path / "run")], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert done.returncode != 0 and "HOST:PORT" in done.stderr and not (tmp_path / "run").exists()
