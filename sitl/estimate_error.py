"""The autopilot's estimate of where it is and how fast it goes, off the truth as PX4 SIH's is.

A real autopilot flies on its estimator's picture of itself, not on the truth. PX4 SIH's was
measured (results/real-autopilots/RENDER.md, docs/camera.md): in flight its horizontal velocity
estimate was about 0.25 m/s off the truth (median; p95 0.56-0.74) and its position about
0.2-0.26 m (p95 0.6), and PX4 flies a velocity setpoint with that estimate, so the vehicle truly
drifts while its own reading says it holds still. Our SITL flies on the truth unless
``[sitl.estimator] velocity_error_std_m_s`` is set. Then, per horizontal axis:

- the velocity error ``e_v`` is a Gauss-Markov (Ornstein-Uhlenbeck) process of standard
  deviation ``velocity_error_std_m_s`` and time constant ``velocity_error_tau_s``;
- the position error ``e_p`` integrates it and is pulled back to the truth, as a GPS corrects
  the estimate, with time constant ``position_pull_tau_s``: ``de_p/dt = e_v - e_p / tau_p``.

Both start from their stationary distribution (the autopilot had flown before the episode),
so an episode's first second is like its last. The numbers are a pure function of the
episode's seed and the FDM step (their own generator stream), so lockstep episodes repeat bit
for bit. The vertical axis and the heading are not disturbed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from sitl.config import EstimatorConfig
from sitl.disturbance import STREAM_ESTIMATE, rng_of_stream
from sitl.dynamics import VehicleState

_BLOCK_STEPS = 128  # normals are drawn for this many FDM steps at a time


@dataclass(frozen=True)
class Stationary:
    """The stationary spread of one axis: std of the velocity and position errors and their
    correlation (from the Lyapunov equation of the two-state process)."""

    velocity_std: float
    position_std: float
    correlation: float

    @classmethod
    def of(cls, cfg: EstimatorConfig) -> Stationary:
        s, tv, tp = cfg.velocity_error_std_m_s, cfg.velocity_error_tau_s, cfg.position_pull_tau_s
        cov = s * s * tv * tp / (tv + tp)
        var_p = cov * tp
        return cls(s, math.sqrt(var_p), cov / (s * math.sqrt(var_p)) if s > 0 else 0.0)


class EstimateError:
    """One episode's horizontal estimate error, advanced once per FDM step."""

    def __init__(self, cfg: EstimatorConfig, seed: tuple[int, ...], dt_s: float) -> None:
        self.cfg = cfg
        self.seed = seed
        self.active = cfg.velocity_error_std_m_s > 0.0
        self._a = math.exp(-dt_s / cfg.velocity_error_tau_s)
        self._kick = cfg.velocity_error_std_m_s * math.sqrt(1.0 - self._a * self._a)
        self._dt, self._pull = dt_s, dt_s / cfg.position_pull_tau_s
        self.step = 0
        self.velocity_ne = (0.0, 0.0)
        self.position_ne = (0.0, 0.0)
        if self.active:
            st = Stationary.of(cfg)
            z = rng_of_stream(STREAM_ESTIMATE, seed, 0).standard_normal(4)
            vel = (st.velocity_std * z[0], st.velocity_std * z[1])
            off = st.position_std * math.sqrt(1.0 - st.correlation ** 2)
            ratio = st.correlation * st.position_std / st.velocity_std
            self.velocity_ne = (float(vel[0]), float(vel[1]))
            self.position_ne = (float(ratio * vel[0] + off * z[2]), float(ratio * vel[1] + off * z[3]))

    def advance(self) -> None:
        """One FDM step of both processes (exact for the velocity, Euler for the position)."""
        if not self.active:
            return
        block, row = divmod(self.step, _BLOCK_STEPS)
        zn, ze = _normals(self.seed, block)[row]
        (vn, ve), (pn, pe) = self.velocity_ne, self.position_ne
        dt, pull = self._dt, self._pull
        self.position_ne = (pn + dt * vn - pull * pn, pe + dt * ve - pull * pe)
        self.velocity_ne = (self._a * vn + self._kick * float(zn), self._a * ve + self._kick * float(ze))
        self.step += 1

    def estimate(self, truth: VehicleState) -> VehicleState:
        """The state as the autopilot believes it: the truth itself when there is no error."""
        if not self.active:
            return truth
        (n, e, d), (vn, ve, vd) = truth.position_ned_m, truth.velocity_ned_m_s
        (en, ee), (wn, we) = self.position_ne, self.velocity_ne
        return replace(truth, position_ned_m=(n + en, e + ee, d), velocity_ned_m_s=(vn + wn, ve + we, vd))


@lru_cache(maxsize=8)
def _normals(seed: tuple[int, ...], block: int) -> np.ndarray:
    """Standard normals (north, east) for FDM steps ``block * B .. block * B + B - 1``."""
    return rng_of_stream(STREAM_ESTIMATE, seed, 1 + block).standard_normal((_BLOCK_STEPS, 2))


@dataclass(frozen=True)
class Fit:
    """An estimate error's parameters as measured from a vehicle's estimate against its truth."""

    velocity_error_std_m_s: float
    velocity_error_tau_s: float
    position_pull_tau_s: float
    position_error_std_m: float
    samples: int

    def config(self) -> EstimatorConfig:
        return EstimatorConfig(velocity_error_std_m_s=round(self.velocity_error_std_m_s, 3),
                               velocity_error_tau_s=round(self.velocity_error_tau_s, 2),
                               position_pull_tau_s=round(self.position_pull_tau_s, 2))


Segment = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One stretch of flight: times (s, increasing), velocity errors (N x 2, north and east, m/s)
and position errors (N x 2, m), estimate minus truth."""


def fit(segments: list[Segment], resample_s: float = 0.1, max_lag_s: float = 20.0) -> Fit:
    """The three parameters that give these errors' spread and memory: the velocity error's rms
    per axis; its correlation time (where its autocorrelation, pooled over the segments and both
    axes on a uniform ``resample_s`` grid, first falls below 1/e); and the position pull time
    that, with those two, gives the position error's rms (the stationary law of
    :class:`Stationary`, solved for ``tau_p``)."""
    grids = []
    for t, vel, _ in segments:
        if len(t) < 2:
            continue
        tt = np.arange(t[0], t[-1], resample_s)
        grids.append(np.stack([np.interp(tt, t, vel[:, i]) for i in range(2)], axis=1))
    vel_all = np.concatenate([v for _, v, _ in segments])
    pos_all = np.concatenate([p for _, _, p in segments])
    var_v = float(np.mean(vel_all ** 2))
    var_p = float(np.mean(pos_all ** 2))
    tau_v = _correlation_time(grids, resample_s, int(max_lag_s / resample_s))
    a = var_v * tau_v
    tau_p = (var_p + math.sqrt(var_p * var_p + 4.0 * a * var_p * tau_v)) / (2.0 * a)
    return Fit(math.sqrt(var_v), tau_v, tau_p, math.sqrt(var_p), len(vel_all))


def _correlation_time(grids: list[np.ndarray], dt: float, max_lag: int) -> float:
    """The first lag (s) where the pooled autocorrelation falls below 1/e, interpolated."""
    zero = sum(float(np.sum(g * g)) for g in grids)
    previous = 1.0
    for k in range(1, max_lag + 1):
        pairs = sum(float(np.sum(g[k:] * g[:-k])) for g in grids if len(g) > k)
        count = sum(2 * (len(g) - k) for g in grids if len(g) > k)
        if count == 0:
            break
        rho = pairs / count / (zero / sum(2 * len(g) for g in grids))
        if rho < math.exp(-1.0):
            return dt * (k - 1 + (previous - math.exp(-1.0)) / (previous - rho))
        previous = rho
    raise ValueError(f"the velocity error stays correlated beyond {max_lag * dt:.0f} s: segments too short to measure it")
