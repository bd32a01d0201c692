"""PX4's failsafe (in PX4 a part of the commander): what the vehicle does when its inputs stop.

Offboard setpoints older than COM_OF_LOSS_T: hold (AUTO.LOITER); still lost after
COM_OBL_LAND_T more: land. Sticks silent for 0.5 s in position mode: hold where it is. Runs
first in every FDM step, before the mode's own progress (sitl/vehicle.py).
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
        if mode is Mode.OFFBOARD or mode is Mode.AUTO_LOITER:
            self._offboard_loss(t_s)
        elif mode is Mode.POSCTL:
            self._sticks_silent(t_s)

    def _offboard_loss(self, t_s: float) -> None:
        st, params = self.status, self.v.params
        hold_s = params.get("COM_OF_LOSS_T")
        if st.mode is Mode.OFFBOARD and t_s - st.last_offboard_s > hold_s:
            self.v.say(mavlink.MAV_SEVERITY_WARNING, "Offboard setpoints lost: holding")
            self.commander.enter(Mode.AUTO_LOITER)
            st.failsafe_since_s = t_s
        elif st.failsafe_since_s is not None and st.mode is Mode.AUTO_LOITER:
            if t_s - st.failsafe_since_s > params.get("COM_OBL_LAND_T") and not st.landed:
                self.v.say(mavlink.MAV_SEVERITY_WARNING, "Offboard still lost: landing")
                self.commander.enter(Mode.AUTO_LAND)

    def _sticks_silent(self, t_s: float) -> None:
        st = self.status
        if st.mode is Mode.POSCTL and t_s - st.manual_at_s > STICKS_SILENT_S and not st.holding():
            st.setpoint = hold_setpoint(self.v.state)
