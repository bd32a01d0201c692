"""Real-flight disturbances of the simulated task, one scalar ``level`` from none to the maxima.

The paper names unmodeled non-linearities, dynamic range limitations and exogenous gusts for
real flight. The SITL stands in for them with: a steady wind and MIL-F-8785C turbulence through
JSBSim's own atmosphere, a random initial heading, the ground vehicle driving, noise and a small
misalignment of the camera, noise on the attitude the vehicle reports, and a camera latency.

:class:`EpisodeDisturbance` is one episode's draw, a pure function of the
:class:`~sitl.config.DisturbanceConfig` and the episode's seed. Its random numbers come from their
own generator stream (:data:`STREAM_EPISODE`), so the episode starts (drawn from the world's
generator) are those of an undisturbed run; and they are drawn whatever the level, so two levels
with the same seed differ only in how large each component is (wind from the same direction,
the same turbulence sequence, ...). Per-step noise (telemetry attitude, camera pixels) is a pure
function of the episode's seed and the FDM step, so an episode repeats bit for bit however often
and whenever its messages and frames are sent. Level 0 draws only zeros, and every consumer skips
a component whose size is zero: the vehicle is then exactly the undisturbed one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from statistics import NormalDist

import numpy as np

from sitl.config import DisturbanceConfig
from sitl.dynamics import Atmosphere

STREAM_EPISODE = 7  # generator streams: the per-episode draw,
STREAM_ATTITUDE = 8  # the noise of the reported attitude and rates (per block of FDM steps),
STREAM_NOISE_FIELD = 9  # the episode's pixel noise field,
STREAM_NOISE_WINDOW = 10  # and where each frame's noise lies in it,
STREAM_ESTIMATE = 11  # the autopilot's estimate error (sitl/estimate_error.py)
JSBSIM_SEED_MAX = 2_147_483_646  # JSBSim's minstd generator: seeds 1 .. 2^31 - 2 are distinct
_ATTITUDE_BLOCK_STEPS = 128  # attitude noise is drawn for this many FDM steps at a time
_NOISE_LEVELS = 1 << 16  # pixel noise: uniform 16-bit draws mapped through a normal quantile table

SeedLike = int | Sequence[int]


def _entropy(seed: SeedLike) -> tuple[int, ...]:
    return (int(seed),) if isinstance(seed, (int, np.integer)) else tuple(int(s) for s in seed)


def rng_of_stream(stream: int, seed: tuple[int, ...], *counter: int) -> np.random.Generator:
    """The generator of one stream of one episode (and one block or step). The seed's length
    is part of the key: numpy's SeedSequence would take (5,) and (5, 0) for the same seed."""
    return np.random.default_rng([stream, len(seed), *seed, *counter])


@dataclass(frozen=True)
class EpisodeDisturbance:
    """What disturbs one episode; all zeros (the default) disturbs nothing."""

    level: float = 0.0
    wind_ne_m_s: tuple[float, float] = (0.0, 0.0)  # the air's velocity (where it blows to)
    turbulence_w20_m_s: float = 0.0
    turbulence_seed: int = 1  # JSBSim's atmosphere/randomseed
    yaw_rad: float = 0.0  # initial heading
    vehicle_velocity_ne_m_s: tuple[float, float] = (0.0, 0.0)  # added to the world's own
    image_noise_std: float = 0.0
    camera_mount_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)  # roll, pitch, yaw of the camera on the body
    attitude_noise_rad: float = 0.0
    rate_noise_rad_s: float = 0.0
    frame_latency_s: float = 0.0
    seed: tuple[int, ...] = (0,)  # the episode's seed: keys the per-step noise

    @classmethod
    def draw(cls, cfg: DisturbanceConfig, seed: SeedLike) -> EpisodeDisturbance:
        """The episode's disturbance; the same (cfg, seed) always gives the same one."""
        entropy = _entropy(seed)
        rng = rng_of_stream(STREAM_EPISODE, entropy)
        # Always drawn, in this order, whatever the level: levels share their random parts.
        wind_dir, vehicle_dir = rng.uniform(0.0, 2.0 * math.pi, size=2)
        yaw_u = float(rng.uniform(-1.0, 1.0))
        mount_u = rng.uniform(-1.0, 1.0, size=3)
        turbulence_seed = int(rng.integers(1, JSBSIM_SEED_MAX + 1))
        lv = cfg.level

        def scaled(maximum: float) -> float:
            return lv * maximum if lv > 0 and maximum > 0 else 0.0

        mount = scaled(cfg.camera_misalignment_max_rad)
        heading = scaled(cfg.heading_range_max_rad)
        return cls(
            level=lv,
            wind_ne_m_s=_polar(scaled(cfg.wind_speed_max_m_s), float(wind_dir)),
            turbulence_w20_m_s=scaled(cfg.turbulence_w20_max_m_s),
            turbulence_seed=turbulence_seed,
            yaw_rad=yaw_u * heading if heading else 0.0,
            vehicle_velocity_ne_m_s=_polar(scaled(cfg.vehicle_speed_max_m_s), float(vehicle_dir)),
            image_noise_std=scaled(cfg.image_noise_max_std),
            camera_mount_rad=(
                (float(mount_u[0] * mount), float(mount_u[1] * mount), float(mount_u[2] * mount))
                if mount else (0.0, 0.0, 0.0)
            ),
            attitude_noise_rad=scaled(cfg.attitude_noise_max_rad),
            rate_noise_rad_s=scaled(cfg.rate_noise_max_rad_s),
            frame_latency_s=scaled(cfg.frame_latency_max_s),
            seed=entropy,
        )

    # ----- what the consumers ask ---------------------------------------------------------------
    def atmosphere(self) -> Atmosphere | None:
        """The JSBSim atmosphere of the episode; None when it is calm (the undisturbed model)."""
        if self.wind_ne_m_s == (0.0, 0.0) and self.turbulence_w20_m_s == 0.0:
            return None
        return Atmosphere(self.wind_ne_m_s, self.turbulence_w20_m_s, self.turbulence_seed)

    @property
    def camera_mount(self) -> tuple[float, float, float] | None:
        """The camera's misalignment, or None when it is mounted straight."""
        return None if self.camera_mount_rad == (0.0, 0.0, 0.0) else self.camera_mount_rad

    def latency_steps(self, fdm_rate_hz: float) -> int:
        """The camera latency in whole FDM steps (deterministic in lockstep)."""
        return int(round(self.frame_latency_s * fdm_rate_hz))

    @property
    def noisy_attitude(self) -> bool:
        return self.attitude_noise_rad > 0.0 or self.rate_noise_rad_s > 0.0

    def attitude_noise(self, step: int) -> np.ndarray:
        """Noise (roll, pitch, yaw, p, q, r) added to what the vehicle reports at FDM ``step``."""
        block, row = divmod(step, _ATTITUDE_BLOCK_STEPS)
        a, r = self.attitude_noise_rad, self.rate_noise_rad_s
        return _attitude_block(self.seed, block)[row] * np.array([a, a, a, r, r, r])

    def add_image_noise(self, image: np.ndarray, step: int) -> np.ndarray:
        """``image`` (uint8) plus Gaussian noise of std ``image_noise_std``, saturated; unchanged
        at std 0. The noise is a window, at a random place for each FDM ``step``, of an
        episode's noise field twice the image's size: a function of the seed and the step,
        fresh-looking in every frame, for 0.1 ms instead of 0.7 ms of drawing per frame."""
        if self.image_noise_std <= 0.0:
            return image
        h, w = image.shape[:2]
        up, down = _noise_field(self.seed, self.image_noise_std, image.shape)
        rng = rng_of_stream(STREAM_NOISE_WINDOW, self.seed, step)
        top, left = (int(x) for x in rng.integers(0, (up.shape[0] - h + 1, up.shape[1] - w + 1)))
        return saturated_add(image, up[top:top + h, left:left + w], down[top:top + h, left:left + w])


def saturated_add(image: np.ndarray, up: np.ndarray, down: np.ndarray) -> np.ndarray:
    """``clip(image + up - down, 0, 255)`` for uint8 arrays where, per element, ``up`` or
    ``down`` is 0: two saturating uint8 operations (0.10 ms a frame in a running env, where
    OpenCV's add of an int16 noise, which works in int32, took 0.17), and the same pixels: the
    first operation saturates only where the second adds nothing."""
    import cv2  # here: a SITL without camera does not load OpenCV

    out = cv2.add(image, up)
    return cv2.subtract(out, down, dst=out)


@lru_cache(maxsize=64)
def _attitude_block(seed: tuple[int, ...], block: int) -> np.ndarray:
    """Standard normals for the attitude noise of FDM steps ``block * B .. block * B + B - 1``:
    one generator per block (a second of steps) instead of one per step."""
    rng = rng_of_stream(STREAM_ATTITUDE, seed, block)
    return rng.standard_normal((_ATTITUDE_BLOCK_STEPS, 6))


def _polar(speed: float, direction_rad: float) -> tuple[float, float]:
    if speed == 0.0:
        return (0.0, 0.0)
    return (speed * math.cos(direction_rad), speed * math.sin(direction_rad))


@lru_cache(maxsize=1)
def _normal_quantiles() -> np.ndarray:
    """Standard normal quantiles at the centres of 2^16 equal bins (|z| <= 4.3)."""
    dist = NormalDist()
    return np.array([dist.inv_cdf((i + 0.5) / _NOISE_LEVELS) for i in range(_NOISE_LEVELS)])


@lru_cache(maxsize=16)  # one per episode of each env in the process (grouped vec envs hold several)
def _noise_field(seed: tuple[int, ...], std: float, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """An episode's pixel noise, twice the image's height and width, as its positive and
    negative parts (uint8, one of them 0 at each element): uniform 16-bit draws through a table
    of rounded ``std``-scaled normal quantiles (five times faster than drawing normals)."""
    table = np.round(_normal_quantiles() * std).astype(np.int16)
    rng = rng_of_stream(STREAM_NOISE_FIELD, seed)
    index = rng.integers(0, _NOISE_LEVELS, size=(2 * shape[0], 2 * shape[1], *shape[2:]), dtype=np.uint16)
    noise = table[index]
    return np.clip(noise, 0, 255).astype(np.uint8), np.clip(-noise, 0, 255).astype(np.uint8)
