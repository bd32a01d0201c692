"""The simulator's control surface: episode resets, ground truth, world changes.

A real vehicle has none of this, so it is not MAVLink: JSON lines over TCP (docs/protocols.md).
This module is the pure request -> reply part; the server does the I/O.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from sitl.vehicle import SimVehicle


class RequestError(ValueError):
    """A malformed or unknown request; the reply carries the message."""


def parse_request(line: bytes) -> dict[str, Any]:
    try:
        req = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RequestError(f"not a JSON object: {exc}") from None
    if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
        raise RequestError('a request is a JSON object with a string "cmd"')
    return req


def _vec(values: Any) -> list[float]:
    return [round(float(v), 6) for v in values]


def truth(v: SimVehicle) -> dict[str, Any]:
    s = v.state
    td = v.touchdown
    return {
        "time_boot_ms": v.time_boot_ms,
        "episode": v.episode,
        "vehicle_ned": _vec(s.position_ned_m),
        "vehicle_vel_ned": _vec(s.velocity_ned_m_s),
        "attitude_rad": _vec(s.attitude_rad),
        "pad_ned": _vec(v.world.pad_ned(v.time_s)),
        "wind_ned": _vec(v.dynamics.wind_ned_m_s()),
        "landed": v.landed,
        "armed": v.armed,
        "mode": v.mode.px4_name,
        "touchdown": None if td is None else {**asdict(td), "time_boot_ms": v.boot_ms(td.time_s)},
        "precision_landing": v.precision_landing_state(),
        **failsafe_times(v),
    }


def failsafe_times(v: SimVehicle) -> dict[str, float | None]:
    """Simulation times of the last offboard setpoint and of the offboard-loss failsafe, so a
    test can measure setpoint loss -> hold exactly (docs/reliability.md)."""
    last = v.status.last_offboard_s
    since = v.status.failsafe_since_s
    return {
        "time_s": round(v.time_s, 6),
        "last_setpoint_s": None if last is None or last != last or abs(last) == float("inf") else round(last, 6),
        "failsafe_since_s": None if since is None else round(since, 6),
    }


def info(v: SimVehicle, camera_uri: str | None, clock: str) -> dict[str, Any]:
    w = v.cfg.world
    return {
        "clock": clock,
        "frame_rate_hz": v.cfg.clock.frame_rate_hz,
        "fdm_rate_hz": v.cfg.clock.fdm_rate_hz,
        "camera_uri": camera_uri,
        "time_boot_ms": v.time_boot_ms,
        "world": w.model_dump(),
        "camera": v.cfg.camera.model_dump(),
        "disturbance": v.cfg.disturbance.model_dump(),
        "episode_disturbance": asdict(v.disturbance),
    }


def handle_request(v: SimVehicle, req: dict[str, Any], camera_uri: str | None, clock: str,
                   episode_start_s: float | None = None) -> dict[str, Any]:
    """Apply one request; raises RequestError for bad arguments. ``episode_start_s``: a
    reset's episode starts at this simulation time (see :meth:`SimVehicle.reset_episode`)."""
    cmd = req["cmd"]
    if cmd == "info":
        return {"ok": True, **info(v, camera_uri, clock)}
    if cmd == "truth":
        return {"ok": True, **truth(v)}
    if cmd == "reset":
        seed = req.get("seed")
        if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool) or seed < 0):
            raise RequestError("seed must be a non-negative integer or null")
        start = v.reset_episode(seed, start_s=episode_start_s)
        return {
            "ok": True,
            "episode": v.episode,
            "start_ned": _vec(start),
            "pad_ned": _vec(v.world.pad_ned(v.time_s)),
            "time_boot_ms": v.time_boot_ms,
            "disturbance": asdict(v.disturbance),
        }
    if cmd == "set_ground_vehicle":
        vel = req.get("velocity_ne_m_s")
        if not (isinstance(vel, list) and len(vel) == 2 and all(isinstance(x, (int, float)) for x in vel)):
            raise RequestError("velocity_ne_m_s must be [north, east] in m/s")
        if any(abs(x) > 30 or x != x for x in vel):
            raise RequestError("velocity_ne_m_s components must be finite and within +-30 m/s")
        v.world.set_velocity((float(vel[0]), float(vel[1])), v.time_s)
        return {"ok": True}
    raise RequestError(f"unknown cmd {cmd!r}; known: info, reset, truth, set_ground_vehicle")
