"""`col camera-bridge` end to end: a vehicle's telemetry in over MAVLink, frames out on colf://
that the companion's own camera source reads, stamped with the telemetry's time."""

from __future__ import annotations

import threading
import time
from pathlib import Path

from companion.testing import FakeVehicle
from companion.vision.bridge import run_bridge
from companion.vision.camera import SitlCameraSource


def test_the_bridge_serves_frames_rendered_from_the_vehicles_telemetry(tmp_path: Path) -> None:
    config = tmp_path / "bridge.toml"
    config.write_text("[companion.perception]\nrender_rate_hz = 20.0\n")
    stop = threading.Event()
    ready: list[str] = []
    with FakeVehicle() as fake:
        fake.place(0.0, 0.0, -4.0, 0.0)
        published: list[int] = []
        thread = threading.Thread(target=lambda: published.append(
            run_bridge(fake.connection_string, config, port=0, stop=stop, on_ready=ready.append, connect_timeout_s=10.0)))
        thread.start()
        try:
            deadline = time.monotonic() + 20.0
            while not ready and time.monotonic() < deadline:
                time.sleep(0.05)
            assert ready and ready[0].startswith("colf://127.0.0.1:")
            source = SitlCameraSource(ready[0])
            source.open()
            try:
                frame = None
                while frame is None and time.monotonic() < deadline:
                    frame = source.latest()
                    time.sleep(0.05)
                assert frame is not None
                assert frame.image.shape == (240, 320, 3)
                assert frame.time_boot_ms > 0  # the telemetry's time, not the bridge's clock
            finally:
                source.close()
        finally:
            stop.set()
            thread.join(10.0)
    assert not thread.is_alive() and published and published[0] > 0
