"""The vehicle's precision landing: an autopilot's own, between the vehicle and its algorithm.

The algorithms are pure and per autopilot (PX4's in sitl/px4_precland.py, ArduCopter's in
sitl/ardupilot_plnd.py); this part feeds them the vehicle as its estimator reports it, hands
them LANDING_TARGET and flies their guidance as setpoints. PX4's is here; ArduCopter's, which
depends on its modes, is in sitl/personality.py.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink

from sitl.control import Setpoint
from sitl.landing_target import LandingTargetRejected, TargetMeasurement
from sitl.modes import Mode
from sitl.px4_precland import (
    Guidance,
    PrecLandMode,
    Px4PrecLand,
    Px4State,
    Px4TargetEstimator,
    VehiclePose,
)
from sitl.status import VehicleView

NAN = math.nan


class PrecisionLanding:
    """What every autopilot's precision landing needs of the vehicle; the rest is per autopilot."""

    def __init__(self, v: VehicleView) -> None:
        self.v = v
        self.status = v.status
        self.hold_yaw_rad = 0.0  # the heading flown while it lands: the one it started with
        self.rejected_targets = 0

    def pose(self) -> VehiclePose:
        """The vehicle as its estimator reports it (the local frame of LOCAL_POSITION_NED), with
        the height above what is below it (a distance sensor)."""
        v = self.v
        s, truth = v.estimate, v.state
        tn, te, td = truth.position_ned_m
        height = -td - v.world.surface_height_m(tn, te, s.time_s)  # the sensor measures the truth
        n, e, d = s.position_ned_m
        return VehiclePose(s.time_s, (n, e, d - v.height_offset_m), s.velocity_ned_m_s, s.attitude_rad, height)

    def refuse_target(self, why: str) -> None:
        """A refused LANDING_TARGET: counted, and said now and then (a stream of them must not
        flood STATUSTEXT)."""
        self.rejected_targets += 1
        if self.rejected_targets in (1, 10, 100) or self.rejected_targets % 1000 == 0:
            self.v.say(mavlink.MAV_SEVERITY_CRITICAL, why)

    def guidance_setpoint(self, g: Guidance) -> Setpoint:
        """A precision landing's guidance (in the reported frame) as a controller setpoint."""
        velocity_ff = (g.vn_m_s, g.ve_m_s)
        if g.down_m is None:
            down = g.descent_m_s if g.descent_m_s is not None else self.v.params.get("MPC_LAND_SPEED")
            return Setpoint(position_ned_m=(g.north_m, g.east_m, NAN), velocity_ned_m_s=(*velocity_ff, down),
                            yaw_rad=self.hold_yaw_rad)
        return Setpoint(position_ned_m=(g.north_m, g.east_m, g.down_m + self.v.height_offset_m),
                        velocity_ned_m_s=(*velocity_ff, 0.0), yaw_rad=self.hold_yaw_rad)

    # ----- per autopilot -----------------------------------------------------------------
    def start(self, yaw_rad: float) -> None:
        """The landing mode was entered, heading ``yaw_rad``."""
        raise NotImplementedError

    def measure(self, m: TargetMeasurement) -> bool:
        """LANDING_TARGET; False when it is not used."""
        raise NotImplementedError

    def run(self) -> None:
        """Per FDM step, before the mode's progress: estimate, and in the mode, guide."""
        raise NotImplementedError

    def phase(self) -> str | None:
        """The landing's phase while one runs (ground truth for tests and experiments)."""
        raise NotImplementedError

    def descending(self) -> bool:
        """In a phase that descends (EXTENDED_SYS_STATE says LANDING)."""
        return False


class Px4PrecisionLanding(PrecisionLanding):
    """PX4's: the landing target estimator and AUTO.PRECLAND (always "required")."""

    def __init__(self, v: VehicleView) -> None:
        super().__init__(v)
        self.estimator = Px4TargetEstimator(v.param)
        self.px4 = Px4PrecLand(v.param)

    def start(self, yaw_rad: float) -> None:
        self.px4.start(self.pose(), PrecLandMode.REQUIRED)
        self.hold_yaw_rad = yaw_rad

    def measure(self, m: TargetMeasurement) -> bool:
        try:
            self.estimator.measure(m, self.pose())
        except LandingTargetRejected as exc:
            self.refuse_target(str(exc))
            return False
        return True

    def run(self) -> None:
        """The estimator runs while it has a target; the state machine only in AUTO.PRECLAND.
        (Nothing at all otherwise: this is in every FDM step of every experiment.)"""
        st = self.status
        if st.mode is not Mode.AUTO_PRECLAND and not self.estimator.active:
            return
        pose = self.pose()
        self.estimator.predict(pose)
        if st.mode is not Mode.AUTO_PRECLAND:
            return
        if st.landed and st.touchdown is not None:
            self.px4.landed(pose.time_s)
        guidance = self.px4.update(pose, *self.estimator.take())
        self.px4.events.clear()  # PX4 logs these on its console only, not as STATUSTEXT
        st.setpoint = self.guidance_setpoint(guidance)

    def phase(self) -> str | None:
        """PX4 logs it on its console only."""
        return self.px4.state.value if self.status.mode is Mode.AUTO_PRECLAND else None

    def descending(self) -> bool:
        return self.px4.state in (Px4State.DESCEND_ABOVE_TARGET, Px4State.FINAL_APPROACH, Px4State.FALLBACK)
