"""Typed configuration of the simulated vehicle (the ``[sitl]`` tables of a config file).

Defaults are the paper's setting; ``configs/default.toml`` mirrors them (a test checks).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from colcommon.configio import Section, build, read_toml, section, with_experiment_task
from colcommon.errors import ConfigError

KNOWN_TOP_LEVEL = {"sitl", "companion", "experiment"}


class ClockConfig(Section):
    """How simulation time relates to wall time."""

    mode: Literal["realtime", "lockstep"] = "realtime"
    speed: float = Field(1.0, gt=0, le=1000, description="realtime: sim seconds per wall second")
    fdm_rate_hz: float = Field(126.0, ge=60, le=1000, description="JSBSim step rate")
    frame_rate_hz: float = Field(10.5, gt=0, le=100, description="agent/camera frame rate")
    lockstep_timeout_s: float = Field(
        1.0, gt=0, le=10, description="lockstep: wall time to wait for an answer before advancing"
    )


class NetworkConfig(Section):
    """Where the vehicle talks MAVLink and serves its camera and control surface."""

    host: str = "127.0.0.1"
    udp_local_ports: tuple[int, ...] = (14580, 18570)
    udp_remote_ports: tuple[int, ...] = (14540, 14550)
    tcp_port: int | None = Field(5760, ge=0, le=65535)
    camera_port: int = Field(5600, ge=0, le=65535)
    control_port: int = Field(14600, ge=0, le=65535)
    system_id: int = Field(1, ge=1, le=255)
    rtp_video: str = Field("", description="HOST:PORT to send the camera to as H.264 over RTP (QGroundControl: 127.0.0.1:5600); empty = off")

    @model_validator(mode="after")
    def _pairs(self) -> NetworkConfig:
        if len(self.udp_local_ports) != len(self.udp_remote_ports):
            raise ValueError("udp_local_ports and udp_remote_ports must pair up one to one")
        if self.rtp_video:
            from sitl.rtp import parse_destination

            parse_destination(self.rtp_video)
        return self


class AutopilotConfig(Section):
    """Limits, gains and failsafes of the flight stack (also exposed as MAVLink parameters)."""

    max_speed_xy_m_s: float = Field(5.0, gt=0)
    max_speed_up_m_s: float = Field(3.0, gt=0)
    max_speed_down_m_s: float = Field(2.0, gt=0)
    max_tilt_rad: float = Field(0.6, gt=0, lt=1.2)
    max_yaw_rate_rad_s: float = Field(1.5, gt=0)
    vel_cmd_tau_s: float = Field(
        0.0, ge=0, le=10, description="first-order lag on the horizontal velocity command (0: none); a slower autopilot's response"
    )
    land_speed_m_s: float = Field(0.7, gt=0)
    takeoff_alt_m: float = Field(2.5, gt=0)
    offboard_loss_hold_s: float = Field(1.0, gt=0, description="COM_OF_LOSS_T: no setpoint for this long -> hold (real PX4 SIH reads 1.0)")
    offboard_loss_land_s: float = Field(5.0, gt=0, description="then after this much more -> land")
    # Cascade gains (sitl/control.py), tuned on the JSBSim F450 at 126 Hz.
    pos_p_xy: float = Field(1.0, ge=0, description="position -> velocity, 1/s")
    pos_p_z: float = Field(1.5, ge=0, description="position -> velocity, 1/s")
    vel_p_xy: float = Field(3.5, ge=0, description="velocity error -> acceleration, 1/s")
    vel_i_xy: float = Field(1.0, ge=0, description="1/s^2")
    vel_i_max_xy_m_s2: float = Field(2.0, ge=0)
    vel_p_z: float = Field(5.0, ge=0, description="1/s")
    vel_i_z: float = Field(2.0, ge=0, description="1/s^2")
    vel_i_max_z_m_s2: float = Field(4.0, ge=0)
    vel_i_zone_m_s: float = Field(
        0.3, ge=0, description="horizontal velocity integrators run only below this error"
    )
    att_p_rp: float = Field(7.0, ge=0, description="roll/pitch error -> Euler rate, 1/s")
    att_p_yaw: float = Field(3.0, ge=0, description="yaw error -> yaw rate, 1/s")
    max_rate_rp_rad_s: float = Field(3.5, gt=0)
    rate_p_rp: float = Field(0.08, ge=0, description="rate error -> normalised torque, s/rad")
    rate_i_rp: float = Field(0.2, ge=0)
    rate_d_rp: float = Field(0.002, ge=0)
    rate_i_max: float = Field(0.1, ge=0)
    rate_p_yaw: float = Field(0.3, ge=0)
    rate_i_yaw: float = Field(0.3, ge=0)
    rate_i_max_yaw: float = Field(0.1, ge=0)
    hover_throttle: float = Field(0.415, gt=0, lt=1, description="ESC command that hovers")
    thrust_curve_quadratic: float = Field(
        0.54, gt=0, le=1, description="thrust/weight = q x^2 + (1-q) x, x = throttle/hover"
    )
    # Land detector (sitl/land_detector.py Px4LandDetector; docs/sitl.md "Land detector").
    land_detector: Literal["px4", "contact"] = Field(
        "px4", description="px4: PX4's LNDMC stages (commanded descent, stillness, low thrust); contact: landed at the first settling contact (before 2026-12; experiment files keep it)"
    )
    land_z_vel_max_m_s: float = Field(
        0.25, gt=0, description="LNDMC_Z_VEL_MAX: still below this climb rate; ground contact needs a commanded descent of 1.1x it"
    )
    land_xy_vel_max_m_s: float = Field(1.5, gt=0, description="LNDMC_XY_VEL_MAX: still below this ground speed")
    land_rot_max_deg_s: float = Field(20.0, gt=0, description="LNDMC_ROT_MAX: still below this roll/pitch rate")
    land_trigger_time_s: float = Field(
        1.0, gt=0, description="LNDMC_TRIG_TIME: ground contact, maybe landed, landed take a third each"
    )


class WorldConfig(Section):
    """The landing pad on its ground vehicle, and how episodes start."""

    pad_radius_m: float = Field(0.5, gt=0)
    success_radius_m: float = Field(0.5, gt=0)
    vehicle_length_m: float = Field(4.0, gt=0)
    vehicle_width_m: float = Field(2.0, gt=0)
    vehicle_height_m: float = Field(1.5, ge=0)
    vehicle_velocity_ne_m_s: tuple[float, float] = (0.0, 0.0)
    vehicle_turn_rate_rad_s: float = Field(
        0.0, ge=-1.0, le=1.0, description="the ground vehicle's course turns at this rate (a curve of radius "
        "speed / rate; + clockwise seen from above); 0: straight on")
    vehicle_speed_change: float = Field(
        0.0, ge=0.0, le=1.0, description="its speed swings by this share of itself, sinusoidally over "
        "vehicle_speed_change_period_s (0.5: between half and one and a half times); 0: steady")
    vehicle_speed_change_period_s: float = Field(20.0, gt=0, le=600)
    roof_carries: bool = Field(
        False, description="the roof carries the multirotor as a solid surface does: touchdown friction acts on the "
        "velocity relative to the roof and a multirotor standing on it drives along, through turns and speed changes "
        "(JSBSim flies in the roof's frame while over it: docs/sitl.md); false: the roof is a moving height only (as before)")
    start_height_above_pad_m: float = Field(8.0, gt=0)
    start_xy_range_m: float = Field(3.0, ge=0, description="start x,y uniform in +-range")
    spawn_ne_m: tuple[float, float] = (-6.0, 0.0)
    seed: int = 0


class CameraConfig(Section):
    """The downward camera: pinhole, body-fixed, looking down."""

    enabled: bool = True
    width_px: int = Field(320, ge=16, le=4096)
    height_px: int = Field(240, ge=16, le=4096)
    hfov_deg: float = Field(90.0, gt=10, lt=170)
    encoding: Literal["raw", "jpeg"] = "raw"
    jpeg_quality: int = Field(90, ge=10, le=100)
    stream_rate_hz: float = Field(
        10.5, gt=0, le=100, description="real time: frames per second of sim time (35 for a person's view)"
    )
    texture_seed: int = Field(0, description="seed of the procedural ground texture")
    pad_dot_radius_m: float = Field(0.1, gt=0, description="white centre dot of the pad's marking")
    pad_marker: Literal["none", "aruco", "aruco-disc"] = Field(
        "none",
        description="an ArUco board on the pad (sitl/pad_marker.py) for `col fly --pilot precland`: aruco, black on "
        "white over the pad (it hides the colour disc), or aruco-disc, inked into the dot and the disc so the colour "
        "detector still sees the plain pad; none: the colour pad alone (the experiment's)",
    )
    ground_downsample: int = Field(
        2, ge=1, le=4, description="render the ground at 1/n resolution, then scale up (vehicle and pad: full)"
    )


class DisturbanceConfig(Section):
    """Real-flight disturbances (sitl/disturbance.py, docs/sitl.md "Disturbances").

    Every component is ``level`` times its maximum below (the value at level 1); level 0 is the
    undisturbed vehicle, bit for bit. Random parts are drawn per episode from the episode's seed.
    """

    level: float = Field(0.0, ge=0, le=1, description="0 = none; each component is level x its maximum")
    wind_speed_max_m_s: float = Field(
        10.0, ge=0, le=30, description="steady wind at level 1, direction random per episode"
    )
    turbulence_w20_max_m_s: float = Field(
        10.0, ge=0, le=30, description="MIL-F-8785C wind speed at 20 ft (light 7.7, moderate 15.4), JSBSim Milspec"
    )
    heading_range_max_rad: float = Field(
        math.pi, ge=0, le=math.pi, description="initial yaw uniform in +-range"
    )
    vehicle_speed_max_m_s: float = Field(
        0.5, ge=0, le=10, description="ground vehicle's speed, direction random per episode, added to vehicle_velocity_ne_m_s"
    )
    image_noise_max_std: float = Field(
        10.0, ge=0, le=64, description="Gaussian pixel noise, std in 8-bit levels, fresh every frame"
    )
    camera_misalignment_max_rad: float = Field(
        0.05, ge=0, le=0.2, description="camera mount roll, pitch, yaw each uniform in +-max per episode"
    )
    attitude_noise_max_rad: float = Field(
        0.02, ge=0, le=0.2, description="std of the noise on reported roll, pitch, yaw (ATTITUDE, ATTITUDE_QUATERNION)"
    )
    rate_noise_max_rad_s: float = Field(0.05, ge=0, le=1, description="std of the noise on reported body rates")
    frame_latency_max_s: float = Field(
        0.095, ge=0, le=1, description="camera shows the pose this long ago (rounded to FDM steps; 0.095 s = 1 frame)"
    )


class PersonalityConfig(Section):
    """Which autopilot the vehicle looks like from outside (sitl/personality.py, docs/sitl.md)."""

    autopilot: Literal["px4", "ardupilot"] = Field(
        "px4", description="px4: PX4 modes, OFFBOARD, SYSTEM_TIME lockstep; ardupilot: ArduCopter modes, GUIDED"
    )
    prearm_settle_s: float = Field(
        10.0, ge=0, le=600, description="ardupilot: arming refused this long after boot (EKF settling), with PreArm reasons"
    )
    guid_timeout_s: float = Field(3.0, gt=0, le=60, description="ardupilot: GUID_TIMEOUT, velocity setpoints missing -> stop")


class EstimatorConfig(Section):
    """Where the estimator's local frame is (docs/sitl.md "Local frame"): PX4's origin is where
    its estimator started, not the ground, so heights read on the ground are not 0; and how far
    its horizontal estimate is off the truth (none by default)."""

    height_offset_m: float = Field(
        0.7, ge=-10, le=10, description="px4: reported LOCAL_POSITION_NED z = true z - this (on the ground the height reads +this); ardupilot: always 0 (origin = home)"
    )
    # The horizontal estimate error (sitl/estimate_error.py, docs/sitl.md "The estimate"): off (0)
    # by default; fitted to PX4 SIH: 0.263 m/s, 3.83 s, 0.78 s (results/transfer/matched/fit.json).
    velocity_error_std_m_s: float = Field(
        0.0, ge=0, le=2, description="std per horizontal axis of the velocity estimate's error (Gauss-Markov); 0: the autopilot flies on the truth"
    )
    velocity_error_tau_s: float = Field(2.0, gt=0, le=600, description="time constant of the velocity error")
    position_pull_tau_s: float = Field(
        1.2, gt=0, le=600, description="the position error integrates the velocity error and returns to the truth with this time constant (GPS)"
    )


class SitlConfig(Section):
    personality: PersonalityConfig = PersonalityConfig()
    clock: ClockConfig = ClockConfig()
    network: NetworkConfig = NetworkConfig()
    autopilot: AutopilotConfig = AutopilotConfig()
    estimator: EstimatorConfig = EstimatorConfig()
    world: WorldConfig = WorldConfig()
    camera: CameraConfig = CameraConfig()
    disturbance: DisturbanceConfig = DisturbanceConfig()

    @model_validator(mode="after")
    def _lockstep_is_px4(self) -> SitlConfig:
        if self.personality.autopilot == "ardupilot" and self.clock.mode == "lockstep":
            raise ValueError(
                "lockstep needs the PX4 personality's SYSTEM_TIME frame marker; ArduPilot has no "
                "companion lockstep: run the ardupilot personality with clock mode realtime"
            )
        return self


def check_top_level(data: dict, source: str) -> None:
    unknown = set(data) - KNOWN_TOP_LEVEL
    if unknown:
        raise ConfigError(
            f"{source}: unknown top-level table(s) {sorted(unknown)}; expected some of "
            f"{sorted(KNOWN_TOP_LEVEL)}"
        )


def load_sitl_config(path: str | Path | None = None) -> SitlConfig:
    """The ``[sitl]`` part of a config file, or the embedded defaults when ``path`` is None."""
    if path is None:
        return SitlConfig()
    data = read_toml(path)
    check_top_level(data, str(path))
    return build(SitlConfig, with_experiment_task(data, section(data, "sitl"), EXPERIMENT_TASK), f"[sitl] in {path}")


EXPERIMENT_TASK: dict[tuple[str, str], object] = {
    ("autopilot", "land_detector"): "contact",
    ("estimator", "height_offset_m"): 0.0,
}
"""Settings added after the experiments were designed (PX4's land-detector rule and estimator
offset, 2026-12), with the values their task was run with: an experiment file (one with an
``[experiment]`` table, also the file ``col ppo --config`` takes) that does not name them gets
these, so its committed results stay what its trials give. The companion does the same for its
touchdown assist (companion.config.EXPERIMENT_TASK)."""

