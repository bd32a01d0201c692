"""The rendered camera sees what a real camera would: the SITL's truth when it is fresh, the
estimate when truth is stale or absent, and it says which."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from companion.msg.true_pose import TruePose
from companion.vision.rendered import EstimateError, RenderedCamera
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World
from tests.vision.test_rendered import Clock, snapshot

PAD = (4.0, -2.0)
TRUE_ATTITUDE = (-0.04, 0.06, 1.2)


def truth(n: float, e: float, d: float, t_ms: int = 1234, received_s: float = 10.0) -> TruePose:
    return TruePose(n, e, d, TRUE_ATTITUDE, t_ms, "HIL_STATE_QUATERNION", received_s)


def expected(world: WorldConfig, position: tuple[float, float, float], attitude: tuple[float, float, float]) -> np.ndarray:
    return CameraRenderer(CameraConfig(), World(world)).render(position, attitude, 0.0)


def camera(state: dict, clock: Clock, world: WorldConfig) -> RenderedCamera:
    return RenderedCamera(lambda: state["snap"], CameraConfig(), world, pad_ne_m=PAD, clock=clock, stale_after_s=0.5)


def test_fresh_truth_is_drawn_with_the_pad_where_the_truth_puts_it_and_says_so() -> None:
    world = WorldConfig()
    estimate = snapshot(PAD[0] + 1.5, PAD[1] + 1.0, -4.0)  # the estimate is 1.8 m off the truth
    state = {"snap": replace(estimate, true_pose=truth(PAD[0] + 0.6, PAD[1] - 0.3, -5.0))}
    cam = camera(state, Clock(10.2), world)
    frame = cam.step()
    assert frame is not None and frame.time_boot_ms == 1234  # the truth's own vehicle time
    assert np.array_equal(frame.image, expected(world, (0.6, -0.3, -5.0), TRUE_ATTITUDE))
    assert not np.array_equal(frame.image, expected(world, (1.5, 1.0, -4.0), estimate.attitude_rad))
    assert cam.source_of(frame.frame_number) == "truth" and cam.last_source == "truth"
    assert cam.step() is None  # the same truth is not drawn twice
    assert cam.frame_source_notes() == ["rendered camera: 1 frames from the SITL's truth (HIL_STATE_QUATERNION), "
                                        "0 from the vehicle's estimate",
                                        # the estimate's picture: 0.9 m north, 1.3 m east, 1 m up from the truth's
                                        "estimate off the truth at 1 frames: horizontal median 1.581 m, p95 1.581 m, "
                                        "max 1.581 m; vertical median 1.000 m, max 1.000 m; roll/pitch median "
                                        f"{math.degrees(0.06 - estimate.attitude_rad[1]):.2f} deg, max "
                                        f"{math.degrees(0.06 - estimate.attitude_rad[1]):.2f} deg; yaw median "
                                        f"{abs(math.degrees(TRUE_ATTITUDE[2] - estimate.attitude_rad[2])):.2f} deg, max "
                                        f"{abs(math.degrees(TRUE_ATTITUDE[2] - estimate.attitude_rad[2])):.2f} deg"]
    assert cam.frame_source_notes() == []  # counted again from zero for the next episode


@pytest.mark.parametrize("true_pose", [None, truth(0.0, 0.0, -5.0, received_s=9.0)], ids=["absent", "stale"])
def test_without_fresh_truth_the_estimate_is_drawn_and_the_record_says_so(true_pose: TruePose | None) -> None:
    world = WorldConfig()
    estimate = snapshot(PAD[0] + 1.5, PAD[1] + 1.0, -4.0, received_s=10.0)
    state = {"snap": replace(estimate, true_pose=true_pose)}
    cam = camera(state, Clock(10.2), world)  # a truth heard 1.2 s ago is stale (rule: 0.5 s)
    frame = cam.step()
    assert frame is not None and frame.time_boot_ms == estimate.time_boot_ms
    assert np.array_equal(frame.image, expected(world, (1.5, 1.0, -4.0), estimate.attitude_rad))
    assert cam.source_of(frame.frame_number) == "estimate"
    assert cam.frame_source_notes() == ["rendered camera: 0 frames from the SITL's truth, 1 from the vehicle's estimate"]


def test_the_camera_switches_to_truth_when_it_comes_and_back_when_it_goes() -> None:
    clock = Clock(10.0)
    state = {"snap": snapshot(1.0, 1.0, -4.0, t_ms=1000, received_s=10.0)}
    cam = camera(state, clock, WorldConfig())
    assert cam.step() is not None and cam.last_source == "estimate"
    state["snap"] = replace(snapshot(1.0, 1.0, -4.0, t_ms=1100, received_s=10.1), true_pose=truth(1.2, 0.9, -4.2, 1090, 10.1))
    clock.t = 10.1
    assert cam.step() is not None and cam.last_source == "truth"
    clock.t = 10.7  # the truth went quiet, the estimate did not
    state["snap"] = replace(state["snap"], time_boot_ms=1700, received_s=10.7)
    frame = cam.step()
    assert frame is not None and cam.last_source == "estimate" and frame.time_boot_ms == 1700
    notes = cam.frame_source_notes()
    assert notes[0] == ("rendered camera: 1 frames from the SITL's truth (HIL_STATE_QUATERNION), "
                        "2 from the vehicle's estimate")
    assert notes[1].startswith("estimate off the truth at 1 frames:")  # only a truth frame has a pair


def test_true_heights_come_from_the_true_ground_the_vehicle_stood_on() -> None:
    world = WorldConfig(vehicle_height_m=0.0)
    standing = replace(snapshot(0.0, 0.0, -0.7), landed_state="ON_GROUND", armed=False,
                       true_pose=truth(0.0, 0.0, 0.35))  # the origin's altitude is 0.35 m above the true ground
    state = {"snap": standing}
    cam = camera(state, Clock(10.0), world)
    cam.step()
    position, _ = cam.true_world_pose(truth(PAD[0], PAD[1], -2.65))
    assert position == pytest.approx((0.0, 0.0, -3.0))


def test_the_episode_record_says_what_the_rendered_camera_drew_from() -> None:
    from colcommon.frames import Frame
    from companion.control.arbiter import Phase
    from companion.vision.observer import Observer
    from companion.vision.perception import PadDetector
    from tests.control.test_session import KinematicLink, ScriptedHuman, make_runner, policy_runner

    class Rendered:
        """A rendered camera's frames and its per-record note (companion/vision/rendered.py)."""

        vehicle_time_stamps = True

        def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
            return Frame(0, time_boot_ms, np.zeros((240, 320, 3), np.uint8))

        def latest(self) -> Frame | None:
            return None

        def frame_source_notes(self) -> list[str]:
            return ["rendered camera: 7 frames from the SITL's truth (SIM_STATE), 0 from the vehicle's estimate"]

    runner, _ = make_runner(KinematicLink((0.0, 0.0, -5.0)), ScriptedHuman(set()), runner=policy_runner(), max_steps=4)
    runner.p.observer = Observer(Rendered(), PadDetector(), (320, 240))  # type: ignore[arg-type]
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert "rendered camera: 7 frames from the SITL's truth (SIM_STATE), 0 from the vehicle's estimate" in record.notes


def test_the_estimate_error_is_summarised_per_record_and_counted_afresh() -> None:
    errors = EstimateError()
    assert errors.note() == []  # no frame drawn from truth: nothing to say
    for k in range(20):  # 0.0, 0.1, ... 1.9 m east of the truth, 0.5 m below it, tilted 0.01 rad more in pitch
        errors.add((0.0, 0.1 * k, -4.5), (0.0, 0.0, -5.0), (0.0, 0.01 * k, 0.3), (0.0, 0.0, -0.3))
    note = errors.note(reset=False)
    assert note == ["estimate off the truth at 20 frames: horizontal median 0.950 m, p95 1.805 m, max 1.900 m; "
                    "vertical median 0.500 m, max 0.500 m; roll/pitch median 5.44 deg, max 10.89 deg; "
                    "yaw median 34.38 deg, max 34.38 deg"]  # 0.3 against -0.3 rad
    assert errors.note() == note and errors.note() == []
