"""Joystick commands and their mapping to body-frame velocity setpoints.

A :class:`~companion.msg.command.JoystickCommand` is what people and policies produce and what the dataset records
(order roll, pitch, yaw, throttle, each in [-1, 1]). :class:`CommandMapper` turns it into a
:class:`~companion.msg.setpoint.VelocitySetpoint` in small steps ending in a clip:
deadband -> expo -> scale -> clip. Inputs from misbehaving sources go through
:func:`sanitize` first, so nothing non-finite or out of range ever reaches the vehicle.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.config import CommandsConfig
from companion.msg.command import JoystickCommand, four_values
from companion.msg.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class SanitizeIssues:
    """What :func:`sanitize` had to repair in one input, per kind (number of axes)."""

    non_finite: int = 0
    clamped: int = 0

    @property
    def any(self) -> bool:
        return self.non_finite > 0 or self.clamped > 0


def sanitize(values: Sequence[float] | np.ndarray) -> tuple[JoystickCommand, SanitizeIssues]:
    """Repair untrusted stick values: non-finite -> 0 (neutral), out of range -> clamped.

    For inputs from policies and pilots that may misbehave; the issues say what was repaired
    so that callers can count and log it. A wrong number of values is a programming error
    and raises ValueError.
    """
    arr = four_values(values)
    finite = np.isfinite(arr)
    arr = np.where(finite, arr, 0.0)
    clipped = np.clip(arr, -1.0, 1.0)
    issues = SanitizeIssues(
        non_finite=int(np.count_nonzero(~finite)),
        clamped=int(np.count_nonzero(clipped != arr)),
    )
    return JoystickCommand.from_array(clipped), issues


# --- the transforms, each on an array of stick values ------------------------------------


def deadband(x: np.ndarray, width: float) -> np.ndarray:
    """Zero inside +-width; outside, rescaled so the output is continuous and +-1 stays +-1."""
    if not 0.0 <= width < 1.0:
        raise ValueError(f"deadband width must be in [0, 1), got {width}")
    x = np.asarray(x, dtype=np.float64)
    magnitude = np.maximum(np.abs(x) - width, 0.0) / (1.0 - width)
    return np.sign(x) * magnitude


def expo(x: np.ndarray, amount: float) -> np.ndarray:
    """RC-style expo: (1 - a) x + a x^3, finer control near centre, same end points."""
    if not 0.0 <= amount <= 1.0:
        raise ValueError(f"expo must be in [0, 1], got {amount}")
    x = np.asarray(x, dtype=np.float64)
    return (1.0 - amount) * x + amount * x**3


def scale(x: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """Stick fraction times the physical limit of each axis."""
    return np.asarray(x, dtype=np.float64) * np.asarray(limits, dtype=np.float64)


def clip(x: np.ndarray, limits: np.ndarray) -> tuple[np.ndarray, int]:
    """Clip each axis to +-limit; non-finite becomes 0. Returns the values and how many changed."""
    x = np.asarray(x, dtype=np.float64)
    limits = np.asarray(limits, dtype=np.float64)
    finite = np.isfinite(x)
    safe = np.where(finite, x, 0.0)
    out = np.clip(safe, -limits, limits)
    return out, int(np.count_nonzero(~finite) + np.count_nonzero(out != safe))


def body_velocity(physical: np.ndarray) -> np.ndarray:
    """Physical values ``(..., 4)`` (right, forward, yaw rate, up) -> a setpoint's (forward,
    right, down, yaw rate). ``down = 0.0 - up``, not ``-up``: a centred stick gives +0.0, not -0.0."""
    out = np.asarray(physical, dtype=np.float64)[..., [1, 0, 3, 2]]
    out[..., 2] = 0.0 - out[..., 2]
    return out


# --- the mapper ----------------------------------------------------------------------------


@dataclass(frozen=True)
class MapperCounts:
    """Running totals of a :class:`CommandMapper` (numbers of commands and of axes repaired)."""

    commands: int = 0
    non_finite_axes: int = 0
    clamped_axes: int = 0
    clipped_axes: int = 0


class CommandMapper:
    """JoystickCommand -> body-frame VelocitySetpoint per DESIGN.md's conventions.

    forward = pitch * v_xy_max, right = roll * v_xy_max, down = -throttle * v_z_max,
    yaw rate = yaw * r_max, after deadband and expo. Repairs are counted and logged
    (the first one, then every ``log_every``-th) so that a misbehaving source is visible.
    """

    def __init__(self, cfg: CommandsConfig, log_every: int = 100) -> None:
        self.cfg = cfg
        self._log_every = max(1, log_every)
        # Physical limit per axis in AXES order: roll->right, pitch->forward, yaw, throttle->up.
        self._limits = np.array(
            [cfg.v_xy_max_m_s, cfg.v_xy_max_m_s, cfg.yaw_rate_max_rad_s, cfg.v_z_max_m_s]
        )
        self._counts = MapperCounts()
        self._repairs_logged = 0

    @property
    def counts(self) -> MapperCounts:
        return self._counts

    def to_setpoint(self, cmd: JoystickCommand) -> VelocitySetpoint:
        """Map a valid command; the final clip guarantees the limits whatever the shaping."""
        physical, clipped = self.physical(cmd.to_array())
        self._count(MapperCounts(commands=1, clipped_axes=clipped))
        forward, right, down, yaw_rate = (float(v) for v in body_velocity(physical))
        return VelocitySetpoint(
            forward_m_s=forward, right_m_s=right, down_m_s=down, yaw_rate_rad_s=yaw_rate
        )

    def physical(self, sticks: np.ndarray) -> tuple[np.ndarray, int]:
        """Valid stick values ``(..., 4)`` in :data:`AXES` order -> physical values (right,
        forward, yaw rate, up): deadband -> expo -> scale -> clip, element by element, so a stack
        of commands (companion/rl/batched_env.py) maps exactly as each alone; with the number of
        values the final clip changed. Not counted: :meth:`to_setpoint` counts."""
        shaped = expo(deadband(sticks, self.cfg.deadband), self.cfg.expo)
        return clip(scale(shaped, self._limits), self._limits)

    def command_from_values(self, values: Sequence[float] | np.ndarray) -> JoystickCommand:
        """Untrusted values (a policy's raw output) as a valid command; repairs counted, logged.

        Use this before the arbiter, so that what it chooses between is already valid.
        """
        cmd, issues = sanitize(values)
        if issues.any:
            self._count(
                MapperCounts(non_finite_axes=issues.non_finite, clamped_axes=issues.clamped)
            )
            self._log_repair(values, issues)
        return cmd

    def from_values(self, values: Sequence[float] | np.ndarray) -> VelocitySetpoint:
        """Map untrusted values: :meth:`command_from_values`, then :meth:`to_setpoint`."""
        return self.to_setpoint(self.command_from_values(values))

    def _count(self, delta: MapperCounts) -> None:
        c = self._counts
        self._counts = MapperCounts(
            commands=c.commands + delta.commands,
            non_finite_axes=c.non_finite_axes + delta.non_finite_axes,
            clamped_axes=c.clamped_axes + delta.clamped_axes,
            clipped_axes=c.clipped_axes + delta.clipped_axes,
        )

    def _log_repair(self, values: object, issues: SanitizeIssues) -> None:
        if self._repairs_logged % self._log_every == 0:
            c = self._counts
            log.warning(
                "repaired a joystick command %r (%d non-finite -> 0, %d clamped); totals so "
                "far: %d non-finite, %d clamped axes. Check the policy or input source.",
                values,
                issues.non_finite,
                issues.clamped,
                c.non_finite_axes,
                c.clamped_axes,
            )
        self._repairs_logged += 1
