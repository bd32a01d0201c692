"""Stick values -> the setpoints a session sends, for rows of vehicles at once.

The session maps one command at a time (``CommandMapper.to_setpoint``, then
``SetpointLimiter.apply``, then the link's own limits); the drivers that fly many vehicles in one
process (the batched env, the batched evaluation) do the same arithmetic on a stack of rows here,
the one place they share. Every operation is element by element (the mapper's shaping, the
limiter's clip and rate limit), so a row comes out as that command alone, bit for bit; what
depends on a vehicle's history, the limiter's memory of the last setpoint it let through, is
kept per row.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.commands import CommandMapper, body_velocity
from companion.config import CompanionConfig
from companion.control.safety import SetpointLimiter
from companion.link.base import SetpointLimits
from companion.msg.setpoint import VelocitySetpoint


def check_link_limits(limits: SetpointLimits, setpoints: np.ndarray) -> None:
    """The link's last line of defence over rows of setpoints, with the link's own error
    (ValueError, as the session's link raises for a config whose commands exceed it)."""
    too_fast = np.abs(setpoints[:, :3]).max(axis=1) > limits.max_speed_m_s
    too_fast |= np.abs(setpoints[:, 3]) > limits.max_yaw_rate_rad_s
    for i in np.flatnonzero(too_fast):
        limits.check_velocity(VelocitySetpoint(*(float(v) for v in setpoints[i])))


class SetpointRows:
    """``rows`` vehicles' mappers and limiters: valid sticks ``(n, 4)`` -> body-velocity
    setpoints ``(n, 4)`` (forward, right, down, yaw rate) as each one's session would send them.
    Repairs of invalid values stay with each vehicle's own mapper (they are counted per vehicle)."""

    def __init__(self, cfg: CompanionConfig, rows: int) -> None:
        self._mapper = CommandMapper(cfg.commands)  # its shaping only (no state)
        self._limiter = SetpointLimiter(cfg.commands, cfg.safety)  # its clips only: the memory is below
        self._link_limits = SetpointLimits(cfg.link.setpoint_max_speed_m_s, cfg.link.setpoint_max_yaw_rate_rad_s,
                                           cfg.link.setpoint_max_distance_m)
        self.period_s = 1.0 / cfg.session.control_rate_hz
        self._last = np.zeros((rows, 4))
        self._has_last = np.zeros(rows, dtype=bool)

    def forget(self, row: int) -> None:
        """A new episode on this row: its limiter starts from what is asked (the session's reset)."""
        self._has_last[row] = False

    def setpoints(self, sticks: np.ndarray, rows: Sequence[int] | None = None) -> np.ndarray:
        """The setpoints of ``sticks``, one per row of ``rows`` (None: every row, in order)."""
        index = np.arange(len(self._has_last)) if rows is None else np.asarray(rows, dtype=int)
        physical, _ = self._mapper.physical(sticks)
        out = self._limiter.clipped(body_velocity(physical))
        has = self._has_last[index]
        if has.any() and self.period_s > 0:
            out[has] = self._limiter.rate_limited(out[has], self._last[index[has]], self.period_s)
        self._last[index], self._has_last[index] = out, True
        check_link_limits(self._link_limits, out)
        return out
