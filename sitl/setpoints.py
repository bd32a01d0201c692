"""The setpoint streams: SET_POSITION_TARGET_LOCAL_NED and MANUAL_CONTROL into trajectory setpoints.

Offboard targets are taken in any mode and flown in OFFBOARD (PX4's mavlink receiver publishes
them, the commander decides whether they are flown); sticks fly in position mode as velocities
(PX4's FlightTaskManualPosition). Both are stamped, for the failsafe (sitl/failsafe.py).
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from sitl.control import Setpoint
from sitl.modes import Mode
from sitl.offboard import SetpointRejected, TargetFields, from_reported_frame, to_setpoint
from sitl.status import VehicleView, hold_setpoint

STICK_DEADBAND = 0.05  # every stick this close to centre: hold


class SetpointStreams:
    """Turns each offboard target or stick message into the setpoint it asks for."""

    def __init__(self, v: VehicleView) -> None:
        self.v = v
        self.status = v.status
        self.rejected = 0

    def offboard(self, f: TargetFields) -> bool:
        """Apply SET_POSITION_TARGET_LOCAL_NED; False (and a warning) when it is refused."""
        v, st = self.v, self.status
        s = v.estimate
        f = from_reported_frame(f, v.height_offset_m)
        try:
            sp = to_setpoint(f, s.position_ned_m, s.attitude_rad[2], v.params.get("MPC_XY_VEL_MAX"))
        except SetpointRejected as exc:
            self.refuse(exc)
            return False
        st.last_offboard_s = s.time_s
        st.latest_offboard_sp = sp
        if st.mode is Mode.OFFBOARD:
            st.setpoint = sp
        return True

    def refuse(self, exc: SetpointRejected) -> None:
        """A refused target: counted, and said now and then (a stream of them must not flood
        STATUSTEXT)."""
        self.rejected += 1
        if self.rejected in (1, 10, 100) or self.rejected % 1000 == 0:
            self.v.say(mavlink.MAV_SEVERITY_WARNING, f"Setpoint refused ({self.rejected}): {exc}")

    def manual(self, x: float, y: float, z: float, r: float) -> None:
        """MANUAL_CONTROL sticks fly the vehicle in POSCTL (PX4's position mode)."""
        v, st = self.v, self.status
        st.manual_at_s = v.time_s
        if st.mode is not Mode.POSCTL:
            return
        sticks = [max(-1.0, min(1.0, a / 1000.0)) if math.isfinite(a) else 0.0 for a in (x, y, r)]
        thr = max(0.0, min(1.0, z / 1000.0)) if math.isfinite(z) else 0.5
        climb = (thr - 0.5) * 2.0
        if max(abs(a) for a in (*sticks, climb)) < STICK_DEADBAND:
            if not st.holding():
                st.setpoint = hold_setpoint(v.estimate)
            return
        params = v.params
        vxy = params.get("MPC_XY_VEL_MAX")
        yaw = v.estimate.attitude_rad[2]
        fwd, right = sticks[0] * vxy, sticks[1] * vxy
        c, s_ = math.cos(yaw), math.sin(yaw)
        vz = -climb * (params.get("MPC_Z_VEL_MAX_UP") if climb > 0 else params.get("MPC_Z_VEL_MAX_DN"))
        st.setpoint = Setpoint(
            velocity_ned_m_s=(c * fwd - s_ * right, s_ * fwd + c * right, vz),
            yaw_rate_rad_s=sticks[2] * math.radians(params.get("MPC_MAN_Y_MAX")),
        )
