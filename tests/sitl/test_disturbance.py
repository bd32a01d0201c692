"""Disturbances: the per-episode draw, level 0 = undisturbed, repeatable episodes, and each
component doing what it claims (wind and gusts in JSBSim, heading, a driving ground vehicle,
camera noise, misalignment and latency, attitude noise in the telemetry)."""

from __future__ import annotations

import hashlib
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from colcommon.errors import ConfigError
from sitl.camera import CameraRenderer
from sitl.camera_feed import render_frame
from sitl.config import DisturbanceConfig, SitlConfig, load_sitl_config
from sitl.control_surface import handle_request
from sitl.disturbance import EpisodeDisturbance, saturated_add
from sitl.dynamics import HOME_ALT_M, TURBULENCE_GROUND_ASL_M, Atmosphere, Dynamics
from sitl.modes import Mode
from sitl.offboard import FRAME_BODY_NED, TargetFields
from sitl.telemetry import COMPOSERS, attitude, attitude_quaternion
from sitl.vehicle import SimVehicle

FULL = DisturbanceConfig(level=1.0)
NONE_AT_ALL = DisturbanceConfig(
    level=1.0, wind_speed_max_m_s=0.0, turbulence_w20_max_m_s=0.0, heading_range_max_rad=0.0,
    vehicle_speed_max_m_s=0.0, image_noise_max_std=0.0, camera_misalignment_max_rad=0.0,
    attitude_noise_max_rad=0.0, rate_noise_max_rad_s=0.0, frame_latency_max_s=0.0,
)


def only(**maxima: float) -> DisturbanceConfig:
    """Level 1 with only the given components (all others' maxima 0)."""
    return NONE_AT_ALL.model_copy(update=maxima)


def vehicle(dist: DisturbanceConfig, **world: object) -> SimVehicle:
    cfg = SitlConfig()
    return SimVehicle(cfg.model_copy(update={"disturbance": dist, "world": cfg.world.model_copy(update=world)}))


def body_velocity(forward: float, right: float, down: float, yaw_rate: float) -> TargetFields:
    return TargetFields(FRAME_BODY_NED, 0x5C7, 0, 0, 0, forward, right, down, 0, yaw_rate)


def fly(v: SimVehicle, seed: int | None, steps: int = 480, renderer: CameraRenderer | None = None) -> tuple[list, str]:
    """An episode with a fixed command pattern: the trajectory (pose, velocity, rates, wind at
    each step), and a hash of every telemetry message (all streams, each frame) and of the
    camera images (every 4th frame)."""
    v.reset_episode(seed)
    mav = M.MAVLink(None, 1, 1)
    h = hashlib.sha256()
    trace = []
    for i in range(steps):
        if i % 12 == 0:
            v.offboard_setpoint(body_velocity(math.sin(i / 50), math.cos(i / 70), 0.3, 0.1))
            if i == 12:
                v.request_mode(Mode.OFFBOARD)
            for compose in COMPOSERS.values():
                h.update(compose(v).pack(mav))
            if renderer is not None and i % 48 == 0:
                h.update(render_frame(renderer, v).tobytes())
        s = v.step()
        trace.append((s.position_ned_m, s.velocity_ned_m_s, s.attitude_rad, s.rates_frd_rad_s, v.dynamics.wind_ned_m_s()))
    return trace, h.hexdigest()


# ----- configuration and the draw --------------------------------------------------------------
def test_the_default_is_level_zero_and_draws_nothing() -> None:
    assert SitlConfig().disturbance.level == 0.0
    d = EpisodeDisturbance.draw(DisturbanceConfig(), 5)
    assert replace(d, turbulence_seed=1) == EpisodeDisturbance(seed=(5,))  # drawn, but unused
    assert d.atmosphere() is None and d.camera_mount is None and not d.noisy_attitude
    assert d.latency_steps(126.0) == 0
    image = np.full((4, 4, 3), 100, np.uint8)
    assert d.add_image_noise(image, 3) is image


def test_bad_values_are_config_errors_naming_the_key(tmp_path: Path) -> None:
    f = tmp_path / "d.toml"
    f.write_text("[sitl.disturbance]\nlevel = 1.5\nwind_speed_max_m_s = -1\n")
    with pytest.raises(ConfigError) as info:
        load_sitl_config(f)
    assert "disturbance.level" in str(info.value) and "disturbance.wind_speed_max_m_s" in str(info.value)
    f.write_text("[sitl.disturbance]\ngusts = 3\n")
    with pytest.raises(ConfigError, match="disturbance.gusts"):
        load_sitl_config(f)
    f.write_text("[sitl.disturbance]\nlevel = 0.4\nheading_range_max_rad = 0.5\n")
    assert load_sitl_config(f).disturbance == DisturbanceConfig(level=0.4, heading_range_max_rad=0.5)


def test_the_same_seed_gives_the_same_draw_and_other_seeds_differ() -> None:
    a = EpisodeDisturbance.draw(FULL, 11)
    assert EpisodeDisturbance.draw(FULL, 11) == a
    others = [EpisodeDisturbance.draw(FULL, s) for s in (12, (11, 0), (0, 11))]
    for o in others:
        assert o.wind_ne_m_s != a.wind_ne_m_s and o.turbulence_seed != a.turbulence_seed
        assert o.yaw_rad != a.yaw_rad and o.camera_mount_rad != a.camera_mount_rad


def test_each_component_is_level_times_its_maximum_and_levels_share_the_random_parts() -> None:
    cfg = FULL
    for seed in range(40):
        full = EpisodeDisturbance.draw(cfg, seed)
        half = EpisodeDisturbance.draw(cfg.model_copy(update={"level": 0.5}), seed)
        assert math.hypot(*full.wind_ne_m_s) == pytest.approx(cfg.wind_speed_max_m_s)
        assert math.hypot(*full.vehicle_velocity_ne_m_s) == pytest.approx(cfg.vehicle_speed_max_m_s)
        assert abs(full.yaw_rad) <= cfg.heading_range_max_rad
        assert max(map(abs, full.camera_mount_rad)) <= cfg.camera_misalignment_max_rad
        assert (full.turbulence_w20_m_s, full.image_noise_std, full.frame_latency_s) == (
            cfg.turbulence_w20_max_m_s, cfg.image_noise_max_std, cfg.frame_latency_max_s)
        assert (full.attitude_noise_rad, full.rate_noise_rad_s) == (cfg.attitude_noise_max_rad, cfg.rate_noise_max_rad_s)
        # half the level: the same directions, turbulence sequence and mount axis, half the size
        assert np.allclose(half.wind_ne_m_s, np.multiply(full.wind_ne_m_s, 0.5))
        assert np.allclose(half.vehicle_velocity_ne_m_s, np.multiply(full.vehicle_velocity_ne_m_s, 0.5))
        assert half.yaw_rad == pytest.approx(full.yaw_rad / 2)
        assert np.allclose(half.camera_mount_rad, np.multiply(full.camera_mount_rad, 0.5))
        assert half.turbulence_seed == full.turbulence_seed
    yaws = [EpisodeDisturbance.draw(cfg, s).yaw_rad for s in range(200)]
    assert min(yaws) < -2.5 and max(yaws) > 2.5  # level 1: any heading


# ----- level 0 and the episode starts --------------------------------------------------------
def test_level_zero_is_the_undisturbed_vehicle_bit_for_bit_whatever_the_maxima() -> None:
    big = DisturbanceConfig(level=0.0, wind_speed_max_m_s=30.0, image_noise_max_std=64.0, frame_latency_max_s=1.0)
    default, zero = SimVehicle(SitlConfig()), vehicle(big)
    assert replace(zero.disturbance, turbulence_seed=1) == EpisodeDisturbance(seed=(0, 0))
    renderer = CameraRenderer(SitlConfig().camera, default.world)
    assert fly(default, 5, renderer=renderer) == fly(zero, 5, renderer=CameraRenderer(SitlConfig().camera, zero.world))
    assert zero.dynamics.home_alt_m == HOME_ALT_M and zero.dynamics.wind_ned_m_s() == (0.0, 0.0, 0.0)


def test_episode_starts_do_not_depend_on_the_level() -> None:
    plain, disturbed = SimVehicle(SitlConfig()), vehicle(FULL)
    for seed in (3, None, 8, None):
        assert tuple(plain.reset_episode(seed)) == tuple(disturbed.reset_episode(seed))


# ----- repeatability ----------------------------------------------------------------------------
def test_the_same_seed_gives_the_same_gusts_bit_for_bit_and_another_seed_other_gusts() -> None:
    def gusts(seed: int) -> np.ndarray:
        dyn = Dynamics(ground_asl_m=TURBULENCE_GROUND_ASL_M)
        dyn.set_atmosphere(Atmosphere((3.0, 1.0), 6.0, seed))
        dyn.reset((0.0, 0.0, -5.0))
        out = []
        for _ in range(252):
            dyn.step((0.416,) * 4)
            out.append(dyn.wind_ned_m_s())
        return np.array(out)

    a = gusts(42)
    assert a.tobytes() == gusts(42).tobytes()
    assert np.abs(a - gusts(43)).max() > 0.3


def test_the_same_seed_gives_the_same_disturbed_episode_bit_for_bit() -> None:
    def fresh() -> tuple[SimVehicle, CameraRenderer]:
        v = vehicle(FULL)
        return v, CameraRenderer(SitlConfig().camera, v.world)

    v, renderer = fresh()
    reference = fly(v, 5, renderer=renderer)
    v, renderer = fresh()
    assert fly(v, 5, renderer=renderer) == reference  # trajectory, telemetry and images
    fly(v, 7)  # another episode before it changes nothing (but the clock)
    assert fly(v, 5)[0] == reference[0]
    other = fly(vehicle(FULL), 6)
    assert other[0][-1] != reference[0][-1]


def test_episodes_without_a_seed_follow_the_world_seed() -> None:
    a, b = vehicle(FULL, seed=4), vehicle(FULL, seed=4)
    assert a.disturbance == b.disturbance  # boot: episode 0 of the run
    draws = [(a.reset_episode(None), a.disturbance) for _ in range(3)]
    assert [(tuple(s), d) for s, d in draws] == [(tuple(b.reset_episode(None)), b.disturbance) for _ in range(3)]
    assert len({d.wind_ne_m_s for _, d in draws}) == 3


# ----- what each component does -------------------------------------------------------------------
def test_the_steady_wind_is_what_jsbsim_blows() -> None:
    v = vehicle(only(wind_speed_max_m_s=6.0))
    v.reset_episode(2)
    wind = v.disturbance.wind_ne_m_s
    assert math.hypot(*wind) == pytest.approx(6.0)
    for _ in range(126 * 3):
        v.step()
    assert v.dynamics.wind_ned_m_s() == pytest.approx((*wind, 0.0), abs=1e-6)
    assert math.hypot(*v.state.velocity_ned_m_s[:2]) < 0.1  # the cascade holds its position
    truth = handle_request(v, {"cmd": "truth"}, None, "lockstep")
    assert truth["wind_ned"] == pytest.approx([*wind, 0.0], abs=1e-5)


def test_turbulence_gusts_around_the_wind_near_the_ground_with_the_air_of_home() -> None:
    v = vehicle(only(wind_speed_max_m_s=6.0, turbulence_w20_max_m_s=8.0))
    v.reset_episode(3)
    assert v.dynamics.home_alt_m == HOME_ALT_M  # what the vehicle reports stays at home
    wind = []
    for _ in range(126 * 20):
        v.step()
        wind.append(v.dynamics.wind_ned_m_s())
    w = np.array(wind)
    # MIL-F-8785C low altitude: sigma_w = 0.1 W20 (vertical)
    assert np.std(w[:, 2]) == pytest.approx(0.8, rel=0.3)
    assert np.linalg.norm(w[:, :2].mean(0) - np.array(v.disturbance.wind_ne_m_s)) < 3.0
    fdm = v.dynamics._fdm
    assert fdm["position/h-sl-meters"] < 20.0  # JSBSim's ground at sea level: the low-altitude model
    calm = SimVehicle(SitlConfig())
    calm.reset_episode(3)
    rho = "atmosphere/rho-slugs_ft3"
    assert fdm[rho] == pytest.approx(calm.dynamics._fdm[rho], rel=1e-4)  # the air of 488 m
    alt_mm = COMPOSERS[M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT](v).alt
    assert alt_mm / 1000 == pytest.approx(HOME_ALT_M - v.state.position_ned_m[2], abs=0.01)


def test_gusts_have_their_full_strength_from_the_first_step() -> None:
    """The filters start at rest; the pre-roll in reset runs them up before the episode."""
    first = []
    for seed in range(1, 9):
        dyn = Dynamics(ground_asl_m=TURBULENCE_GROUND_ASL_M)
        dyn.set_atmosphere(Atmosphere((5.0, 0.0), 8.0, seed))
        dyn.reset((0.0, 0.0, -3.0))
        dyn.step((0.416,) * 4)
        first.append(np.subtract(dyn.wind_ned_m_s(), (5.0, 0.0, 0.0)))
    rms = np.sqrt(np.mean(np.square(first), axis=0))
    assert rms[0] > 0.7 and rms[2] > 0.3  # stationary: about 1.5 (along the wind) and 0.8 m/s


def test_the_initial_heading_is_drawn_in_range_and_held() -> None:
    v = vehicle(only(heading_range_max_rad=1.0).model_copy(update={"level": 0.5}))
    yaws = []
    for seed in range(6):
        v.reset_episode(seed)
        assert v.state.attitude_rad[2] == pytest.approx(v.disturbance.yaw_rad, abs=1e-9)
        yaws.append(v.disturbance.yaw_rad)
    assert max(map(abs, yaws)) <= 0.5 and len(set(yaws)) == 6
    for _ in range(126 * 2):
        v.step()
    assert v.state.attitude_rad[2] == pytest.approx(yaws[-1], abs=0.01)


def test_the_ground_vehicle_drives_at_the_drawn_speed_on_top_of_its_own() -> None:
    v = vehicle(only(vehicle_speed_max_m_s=0.8), vehicle_velocity_ne_m_s=(0.5, 0.0))
    v.reset_episode(4)
    drift = np.array(v.disturbance.vehicle_velocity_ne_m_s)
    assert np.linalg.norm(drift) == pytest.approx(0.8)
    pad0, t0 = v.world.pad_ned(v.time_s), v.time_s
    for _ in range(252):
        v.step()
    moved = (v.world.pad_ned(v.time_s) - pad0)[:2] / (v.time_s - t0)
    assert moved == pytest.approx(drift + [0.5, 0.0])
    handle_request(v, {"cmd": "set_ground_vehicle", "velocity_ne_m_s": [0.0, 0.0]}, None, "lockstep")
    assert v.world.velocity_ne == pytest.approx(drift)  # the episode's drive stays


def test_image_noise_has_the_configured_std_and_repeats_per_step() -> None:
    v = vehicle(only(image_noise_max_std=8.0))
    v.reset_episode(1)
    renderer = CameraRenderer(SitlConfig().camera, v.world)
    s = v.state
    clean = renderer.render(s.position_ned_m, s.attitude_rad, s.time_s).astype(float)
    noisy = render_frame(renderer, v)
    diff = noisy.astype(float) - clean
    assert diff.std() == pytest.approx(8.0, rel=0.05) and abs(diff.mean()) < 0.2
    assert np.array_equal(render_frame(renderer, v), noisy)  # a function of the step
    v.step()
    assert not np.array_equal(v.disturbance.add_image_noise(clean.astype(np.uint8), 1), noisy)


def test_a_misaligned_camera_sees_as_if_the_vehicle_were_tilted() -> None:
    v = vehicle(only(camera_misalignment_max_rad=0.05))
    v.reset_episode(2)
    mount = v.disturbance.camera_mount
    assert mount is not None and max(map(abs, mount)) <= 0.05
    renderer = CameraRenderer(SitlConfig().camera, v.world)
    pos, t = (0.5, -0.3, -6.0), v.time_s
    assert np.array_equal(renderer.render(pos, (0.0, 0.0, 0.0), t, mount), renderer.render(pos, mount, t))
    roll = (0.04, 0.0, 0.0)
    pad = v.world.pad_ned(t)
    u0, _ = renderer.project(pad, (pad[0], pad[1], -6.0), (0, 0, 0))
    u1, _ = renderer.project(pad, (pad[0], pad[1], -6.0), (0, 0, 0), roll)
    assert u1 - u0 == pytest.approx(renderer.fx * math.tan(0.04), rel=1e-6)  # as a vehicle rolled right (docs/camera.md)


def test_frame_latency_shows_the_pose_of_k_frames_ago() -> None:
    two_frames = 2 / 10.5
    v = vehicle(only(frame_latency_max_s=two_frames))
    assert v.disturbance.latency_steps(126.0) == 24
    renderer = CameraRenderer(SitlConfig().camera, v.world)
    v.reset_episode(3)
    start = v.state
    v.offboard_setpoint(body_velocity(2.0, 1.0, 0.5, 0.3))
    v.request_mode(Mode.OFFBOARD)
    frame_states = [v.state]
    for frame in range(8):
        for _ in range(12):
            v.offboard_setpoint(body_velocity(2.0, 1.0, 0.5, 0.3))
            v.step()
        frame_states.append(v.state)
        shown = frame_states[-3] if frame >= 1 else start
        assert v.camera_state == shown
        expected = renderer.render(shown.position_ned_m, shown.attitude_rad, shown.time_s)
        assert np.array_equal(render_frame(renderer, v), expected)
    assert v.state.position_ned_m != v.camera_state.position_ned_m


def test_telemetry_attitude_carries_the_configured_noise_and_the_flight_does_not() -> None:
    v = vehicle(only(attitude_noise_max_rad=0.02, rate_noise_max_rad_s=0.05))
    v.reset_episode(5)
    errors = []
    for _ in range(2000):
        v.step()
        s, msg = v.state, attitude(v)
        q = attitude_quaternion(v)
        assert (q.rollspeed, q.pitchspeed, q.yawspeed) == (msg.rollspeed, msg.pitchspeed, msg.yawspeed)
        err_yaw = (msg.yaw - s.attitude_rad[2] + math.pi) % (2 * math.pi) - math.pi
        errors.append((msg.roll - s.attitude_rad[0], msg.pitch - s.attitude_rad[1], err_yaw,
                       msg.rollspeed - s.rates_frd_rad_s[0], msg.pitchspeed - s.rates_frd_rad_s[1],
                       msg.yawspeed - s.rates_frd_rad_s[2]))
        assert -math.pi <= msg.yaw <= math.pi
    std = np.std(np.array(errors), axis=0)
    assert std[:3] == pytest.approx([0.02] * 3, rel=0.1)
    assert std[3:] == pytest.approx([0.05] * 3, rel=0.1)
    assert attitude(v).roll == attitude(v).roll  # the same step reports the same noise
    truth = handle_request(v, {"cmd": "truth"}, None, "lockstep")
    assert truth["attitude_rad"] == pytest.approx(list(v.state.attitude_rad), abs=1e-6)
    # only the reports are noisy: the vehicle flies exactly as the undisturbed one
    assert fly(vehicle(only(attitude_noise_max_rad=0.02)), 5)[0] == fly(SimVehicle(SitlConfig()), 5)[0]


def test_the_control_surface_reports_the_episodes_disturbance() -> None:
    v = vehicle(FULL.model_copy(update={"level": 0.3}))
    reply = handle_request(v, {"cmd": "reset", "seed": 9}, None, "lockstep")
    expected = EpisodeDisturbance.draw(v.cfg.disturbance, 9)
    assert reply["disturbance"]["wind_ne_m_s"] == pytest.approx(list(expected.wind_ne_m_s))
    assert reply["disturbance"]["level"] == 0.3
    info = handle_request(v, {"cmd": "info"}, None, "lockstep")
    assert info["disturbance"]["level"] == 0.3
    assert info["episode_disturbance"]["yaw_rad"] == pytest.approx(expected.yaw_rad)


# ----- over the wire ------------------------------------------------------------------------------
def lockstep_run(config: Path, seed: int, frames: int) -> tuple[list, list[str], dict]:
    """A disturbed lockstep episode flown over UDP with the camera: telemetry, frames, truth."""
    from companion.simulator import SimulatorClient, start_sitl
    from companion.vision.camera import open_camera
    from tests.mav_client import MavTestClient

    c = MavTestClient()
    sitl = start_sitl(c.port, clock="lockstep", config=config, camera=True)
    camera = open_camera(sitl.ports["camera_uri"])
    try:
        c.wait_for(lambda m: m.get_type() == "SYSTEM_TIME")
        ctl = SimulatorClient("127.0.0.1", sitl.control_port)
        t0 = ctl.reset(seed=seed)["time_boot_ms"]
        telemetry: list[tuple] = []
        images: list[str] = []
        truth: dict = {}
        while not truth:
            for m in c.pump(2.0):
                if m.get_type() in ("ATTITUDE", "LOCAL_POSITION_NED") and m.time_boot_ms > t0:
                    telemetry.append(tuple(m.to_dict().values()))
                if m.get_type() == "SYSTEM_TIME" and m.time_boot_ms > t0 and not truth:
                    frame = camera.frame_at(m.time_boot_ms, timeout_s=1.0)
                    assert frame is not None and frame.time_boot_ms == m.time_boot_ms
                    images.append(hashlib.sha256(frame.image.tobytes()).hexdigest())
                    k = len(images)
                    if k == frames:  # the SITL waits for this frame's answer: truth of this frame
                        truth = ctl.truth()
                        break
                    if k == 2:  # before the answer, so that it lands in this frame whatever the timing
                        c.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0))
                    c.body_velocity(math.sin(0.1 * k), math.cos(0.07 * k), 0.3, 0.2, echo_ms=m.time_boot_ms)
        ctl.close()
        return telemetry, images, truth
    finally:
        camera.close()
        sitl.stop()
        c.close()


@pytest.mark.e2e
def test_a_disturbed_lockstep_episode_repeats_bit_for_bit_over_the_wire(tmp_path: Path) -> None:
    config = tmp_path / "disturbed.toml"
    config.write_text("[sitl.disturbance]\nlevel = 1.0\n")
    a = lockstep_run(config, seed=4, frames=30)
    b = lockstep_run(config, seed=4, frames=30)
    assert len(a[0]) > 50 and len(set(a[1])) == 30
    assert a[:2] == b[:2]
    assert a[2]["vehicle_ned"] == b[2]["vehicle_ned"] and a[2]["wind_ned"] == b[2]["wind_ned"]
    assert math.hypot(*a[2]["wind_ned"][:2]) > 3.0


def test_saturated_add_is_the_clipped_sum_of_image_and_noise() -> None:
    rng = np.random.default_rng(11)
    image = rng.integers(0, 256, size=(60, 80, 3), dtype=np.uint8)
    image[:5] = 0
    image[-5:] = 255  # both saturations reached
    noise = rng.integers(-300, 301, size=image.shape)  # beyond the uint8 range too
    up, down = np.clip(noise, 0, 255).astype(np.uint8), np.clip(-noise, 0, 255).astype(np.uint8)
    want = np.clip(image.astype(int) + noise, 0, 255).astype(np.uint8)
    assert np.array_equal(saturated_add(image, up, down), want)


def test_image_noise_of_a_frame_is_the_clipped_sum_with_a_window_of_the_episodes_field() -> None:
    d = EpisodeDisturbance(image_noise_std=20.0, seed=(4,))
    image = np.full((48, 64, 3), 128, np.uint8)
    image[:, :8] = 250
    noisy = d.add_image_noise(image, 9)
    diff = noisy.astype(int) - image
    assert diff[:, 8:].std() == pytest.approx(20.0, rel=0.1)
    assert (noisy[:, :8] <= 255).all() and diff[:, :8].max() <= 5  # saturated, not wrapped
    assert np.array_equal(d.add_image_noise(image, 9), noisy) and not np.array_equal(d.add_image_noise(image, 10), noisy)
