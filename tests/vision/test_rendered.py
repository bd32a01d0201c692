"""The camera rendered from a vehicle's telemetry: the frame our SITL renders for the same pose,
stamped with the telemetry's time, and no frame at all when telemetry stops."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from companion.config import PerceptionConfig
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.perception import PadDetector
from companion.vision.rendered import RenderedCamera
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World


def snapshot(n: float, e: float, d: float, t_ms: int = 1000, received_s: float = 10.0,
             attitude: tuple[float, float, float] = (0.05, -0.03, 0.4)) -> VehicleSnapshot:
    return VehicleSnapshot(
        received_s=received_s, time_boot_ms=t_ms, frame_time_boot_ms=None, system_id=1, autopilot="PX4", armed=True,
        mode="OFFBOARD", landed_state="IN_AIR", position_ned_m=(n, e, d), velocity_ned_m_s=(0.0, 0.0, 0.0),
        attitude_rad=attitude, rates_frd_rad_s=(0.0, 0.0, 0.0), heartbeat_s=received_s, position_valid=True,
        attitude_valid=True,
    )


class Clock:
    def __init__(self, t: float = 10.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def test_the_frame_is_our_sitls_frame_for_the_same_pose_with_the_pad_where_configured() -> None:
    world = WorldConfig()
    state = {"snap": snapshot(4.0 + 0.6, -2.0 - 0.3, -5.0)}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), world, pad_ne_m=(4.0, -2.0), clock=Clock())
    frame = cam.step()
    assert frame is not None and frame.time_boot_ms == 1000  # the telemetry it was rendered from
    expected = CameraRenderer(CameraConfig(), World(world)).render((0.6, -0.3, -5.0), (0.05, -0.03, 0.4), 0.0)
    assert np.array_equal(frame.image, expected)
    pad = PadDetector(PerceptionConfig()).detect(frame.image)
    assert pad is not None  # the pad is in view, near the centre of a vehicle 0.67 m off it
    assert abs(pad.u_px - 159.5) < 80 and abs(pad.v_px - 119.5) < 80


def test_heights_come_from_the_ground_the_vehicle_stood_on() -> None:
    world = WorldConfig(vehicle_height_m=0.0)
    on_ground = replace(snapshot(0.0, 0.0, -0.7), landed_state="ON_GROUND", armed=False)  # PX4: z=0 is not the ground
    state = {"snap": on_ground}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), world, clock=Clock())
    cam.step()
    state["snap"] = snapshot(0.0, 0.0, -3.7, t_ms=2000)
    position, _ = cam.world_pose(state["snap"])
    assert position == pytest.approx((0.0, 0.0, -3.0))


def test_stale_telemetry_gives_no_frame_and_says_why_then_frames_resume() -> None:
    clock = Clock(10.0)
    state = {"snap": snapshot(0.0, 0.0, -4.0, received_s=10.0)}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), WorldConfig(), clock=clock, stale_after_s=0.5)
    assert cam.latest() is None and cam.no_telemetry  # nothing rendered yet
    assert cam.step() is not None and cam.latest() is not None
    clock.t = 11.0  # the link went quiet: the last frame is not served as fresh
    assert cam.step() is None
    assert cam.latest() is None and "no telemetry for 1.0 s" in (cam.no_telemetry or "")
    assert cam.frame_at(0, timeout_s=0.0) is None
    state["snap"] = snapshot(0.0, 0.0, -4.0, t_ms=2000, received_s=11.0)
    frame = cam.step()
    assert frame is not None and cam.latest() is frame and cam.no_telemetry is None
    assert cam.step() is None  # the same telemetry is not rendered twice


def test_a_non_finite_pose_is_no_frame_not_a_crash() -> None:
    state = {"snap": snapshot(float("nan"), 0.0, -4.0)}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), WorldConfig(), clock=Clock())
    assert cam.step() is None and "unusable pose" in (cam.no_telemetry or "")


def test_a_driving_pad_starts_again_at_its_point_at_each_hand_over_and_is_drawn_where_it_drove() -> None:
    world = WorldConfig(vehicle_height_m=0.0, vehicle_velocity_ne_m_s=(1.0, 0.0))
    state = {"snap": snapshot(4.0, -2.0, -5.0, t_ms=1000)}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), world, pad_ne_m=(4.0, -2.0), clock=Clock())
    cam.step()  # the world's clock starts at the first frame; the pad drives during the flight to the start
    assert cam.pad_ne_at(31_000) == pytest.approx((34.0, -2.0))
    cam.begin_episode(31_000, drift_ne_m_s=(0.0, 0.5))  # the hand-over: back at its point, with the episode's drift
    assert cam.pad_ne_at(31_000) == pytest.approx((4.0, -2.0))
    assert cam.pad_ne_at(33_000) == pytest.approx((6.0, -1.0))  # 2 s at (1, 0.5) m/s
    detector = PadDetector(PerceptionConfig())
    seen = []
    for t_ms in (31_000, 33_000):  # the vehicle hovers over the pad's point: the pad drives out from under it
        state["snap"] = snapshot(4.0, -2.0, -5.0, t_ms=t_ms, received_s=10.0)
        frame = cam.step()
        assert frame is not None
        pad = detector.detect(frame.image)
        assert pad is not None
        seen.append((pad.u_px, pad.v_px))
    assert seen[0] != pytest.approx(seen[1], abs=5.0)  # drawn where it drove, not where it started


def test_a_still_pad_stays_where_it_is_at_every_hand_over() -> None:
    state = {"snap": snapshot(0.0, 0.0, -5.0)}
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), WorldConfig(), pad_ne_m=(1.0, 2.0), clock=Clock())
    cam.step()
    cam.begin_episode(50_000)
    assert cam.pad_ne_at(90_000) == (1.0, 2.0)
