"""``col camera-bridge``: the rendered camera as a stream, beside any autopilot.

It listens to the vehicle on a MAVLink connection of its own (PX4: the ground-station link,
``udpin:0.0.0.0:14550``; anything that forwards telemetry), renders the downward view from the
telemetry it hears (companion/vision/rendered.py) and serves it on ``colf://HOST:PORT``, the
stream our SITL serves, so ``col fly --camera colf://HOST:PORT`` reads it unchanged, and
optionally as H.264 over RTP for a ground station. A second connection keeps the bridge apart
from the companion (either can restart); inside ``col fly``, ``--camera render`` uses the
companion's own telemetry instead (no second port; the frame and the observation share a pose).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

from colcommon.frames import Frame
from companion.config import load_companion_config
from companion.link import open_link
from companion.link.truth import ask_for_truth
from companion.vision.rendered import RenderedCamera
from sitl.config import load_sitl_config
from sitl.frames import FrameServer

log = logging.getLogger(__name__)


def publish_frames(camera: RenderedCamera, sinks: list[Callable[[Frame], None]], stop: threading.Event,
                   poll_s: float = 0.005) -> int:
    """Hand every new frame of ``camera`` to each sink until ``stop``; returns how many."""
    last = -1
    count = 0
    while not stop.is_set():
        frame = camera.latest()
        if frame is not None and frame.frame_number != last:
            last = frame.frame_number
            for sink in sinks:
                sink(frame)
            count += 1
        stop.wait(poll_s)
    return count


def run_bridge(connection: str, config_path: Path | None = None, host: str = "127.0.0.1", port: int = 5600,
               rtp: str = "", stop: threading.Event | None = None,
               on_ready: Callable[[str], None] | None = None, connect_timeout_s: float = 30.0) -> int:
    """Connect, render and serve until ``stop`` (or Ctrl-C); returns the frames published."""
    cfg = load_companion_config(config_path)
    sitl_cfg = load_sitl_config(config_path)
    stop = stop or threading.Event()
    link = open_link(cfg.link.model_copy(update={"connection": connection, "request_rates_on_connect": True}))
    try:
        link.connect(timeout_s=connect_timeout_s)
        state = link.state()
        if state is not None:  # draw from the SITL's truth where it sends one (companion/link/truth.py)
            ask_for_truth(link, state.autopilot, cfg.perception.render_rate_hz)
        pad_n, pad_e, _ = cfg.session.pad_ned_m
        camera = RenderedCamera(link.state, sitl_cfg.camera, sitl_cfg.world, (pad_n, pad_e),
                                rate_hz=cfg.perception.render_rate_hz)
        server = FrameServer(host, port, sitl_cfg.camera.encoding, sitl_cfg.camera.jpeg_quality)
        sinks: list[Callable[[Frame], None]] = [lambda f: server.publish(f, blocking=False)]
        sender = None
        if rtp:
            from sitl.rtp import RtpVideoSender

            sender = RtpVideoSender(rtp, sitl_cfg.camera.width_px, sitl_cfg.camera.height_px, cfg.perception.render_rate_hz)
            sinks.append(lambda f: sender.publish(f.image))
        camera.open()
        try:
            log.info("camera bridge: %s -> %s%s", connection, server.uri, f" and RTP {rtp}" if rtp else "")
            if on_ready is not None:
                on_ready(server.uri)
            started = time.monotonic()
            count = publish_frames(camera, sinks, stop)
            log.info("camera bridge: %d frames in %.0f s", count, time.monotonic() - started)
            return count
        finally:
            camera.close()
            server.close()
            if sender is not None:
                sender.close()
    finally:
        link.close()
