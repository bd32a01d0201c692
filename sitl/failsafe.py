"""PX4's failsafe (in PX4 a part of the commander): what the vehicle does when its inputs stop.

Offboard setpoints older than COM_OF_LOSS_T: hold (AUTO.LOITER); still lost after
COM_OBL_LAND_T more: land. Setpoints that come back while it holds or lands, airborne and before
anyone chose another mode, give OFFBOARD back, as PX4's failsafe clears its offboard-loss fallback
when the condition clears (real PX4 SIH, measured: results/conformance/setpoint-gap.json). Sticks
silent for 0.5 s in position mode: hold where it is. Runs first in every FDM step, before the
mode's own progress (sitl/vehicle.py).
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from sitl.commander import Commander
from sitl.modes import Mode
from sitl.status import VehicleView, hold_setpoint

STICKS_SILENT_S = 0.5  # position mode holds when MANUAL_CONTROL is this old


class Failsafe:
    """Watches the setpoint streams and switches to hold or land through the commander."""

    def __init__(self, v: VehicleView, commander: Commander) -> None:
        self.v = v
        self.status = v.status
        self.commander = commander

    def check(self, t_s: float) -> None:
        """One FDM step's checks, at simulation time ``t_s``: only the modes a check watches call
        it (this runs in every FDM step of every experiment)."""
        mode = self.status.mode
        if mode is Mode.OFFBOARD or self.status.offboard_lost_s is not None:
            self._offboard_loss(t_s)
        elif mode is Mode.POSCTL:
            self._sticks_silent(t_s)

    def _offboard_loss(self, t_s: float) -> None:
        st, params = self.status, self.v.params
        hold_s = params.get("COM_OF_LOSS_T")
        if st.mode is Mode.OFFBOARD:
            if t_s - st.last_offboard_s > hold_s:
                self.v.say(mavlink.MAV_SEVERITY_WARNING, "Offboard setpoints lost: holding")
                self.commander.enter(Mode.AUTO_LOITER)
                st.failsafe_since_s = st.offboard_lost_s = t_s
            return
        lost_s = st.offboard_lost_s
        if lost_s is None:
            return
        if st.landed or not st.armed or st.mode not in (Mode.AUTO_LOITER, Mode.AUTO_LAND):
            st.offboard_lost_s = None  # on the ground, or the mode is no longer the failsafe's
        elif st.last_offboard_s > lost_s:
            self.v.say(mavlink.MAV_SEVERITY_INFO, "Offboard setpoints regained")
            self.commander.resume_offboard()
        elif st.mode is Mode.AUTO_LOITER and t_s - lost_s > params.get("COM_OBL_LAND_T"):
            self.v.say(mavlink.MAV_SEVERITY_WARNING, "Offboard still lost: landing")
            self.commander.enter(Mode.AUTO_LAND)

    def _sticks_silent(self, t_s: float) -> None:
        st = self.status
        if st.mode is Mode.POSCTL and t_s - st.manual_at_s > STICKS_SILENT_S and not st.holding():
            st.setpoint = hold_setpoint(self.v.estimate)
