"""What the vehicle's parts share: its flight status, as PX4's modules share uORB topics.

PX4's commander, land detector, failsafe and navigator do not reach into one another: each
publishes topics (vehicle_status, vehicle_land_detected, trajectory_setpoint,
offboard_control_mode, manual_control_setpoint) that the others read. The SITL's parts do the
same through one :class:`FlightStatus`, so none needs another's internals, and the order they
run in is the vehicle's alone (:meth:`sitl.vehicle.SimVehicle.step`). What else a part may use
of the vehicle is :class:`VehicleView` (the parts cannot import the vehicle that imports them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from sitl.config import SitlConfig
from sitl.control import HOLD, FlightController, Setpoint
from sitl.dynamics import Dynamics, VehicleState
from sitl.modes import Mode
from sitl.params import ParamStore
from sitl.world import Touchdown, World


@dataclass
class FlightStatus:
    """The topics, one field each; a part writes what PX4's counterpart publishes."""

    mode: Mode = Mode.AUTO_LOITER  # vehicle_status (commander, failsafe)
    armed: bool = False  # vehicle_status (commander)
    armed_at_s: float = -math.inf  # vehicle_status (commander): for the preflight disarm
    setpoint: Setpoint = HOLD  # trajectory_setpoint: what the cascade flies now
    landed_since_s: float | None = 0.0  # vehicle_land_detected (land detector): None in the air
    touchdown: Touchdown | None = None  # ground truth (land detector): the first settling contact of a flight
    last_offboard_s: float = -math.inf  # offboard_control_mode: the last accepted setpoint's time
    latest_offboard_sp: Setpoint | None = None  # that setpoint, flown once OFFBOARD is entered
    manual_at_s: float = -math.inf  # manual_control_setpoint: the sticks' last time
    failsafe_since_s: float | None = None  # failsafe: holding since, after offboard loss
    offboard_lost_s: float | None = None  # failsafe: OFFBOARD lost then; it holds or lands until setpoints return

    @property
    def landed(self) -> bool:
        return self.landed_since_s is not None

    def holding(self) -> bool:
        """The setpoint is a position hold (position set, velocity zero)."""
        sp = self.setpoint
        return sp.velocity_ned_m_s == (0.0, 0.0, 0.0) and not math.isnan(sp.position_ned_m[0])

    def landed_disarmed(self, setpoint: Setpoint) -> None:
        """Back to boot: disarmed, holding ``setpoint``, no flight and no stream behind it (the
        land detector sets the landed state itself)."""
        self.mode = Mode.AUTO_LOITER
        self.armed = False
        self.touchdown = None
        self.setpoint = setpoint
        self.last_offboard_s = -math.inf
        self.latest_offboard_sp = None
        self.failsafe_since_s = None
        self.offboard_lost_s = None
        self.armed_at_s = -math.inf
        self.manual_at_s = -math.inf


def hold_setpoint(state: VehicleState) -> Setpoint:
    """Hold where the vehicle is, with the heading it has."""
    n, e, d = state.position_ned_m
    return Setpoint(position_ned_m=(n, e, d), velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=state.attitude_rad[2])


class LandingStart(Protocol):
    """A precision landing, as the commander starts it on entering its mode."""

    def start(self, yaw_rad: float) -> None: ...


class VehicleView(Protocol):
    """What a part may use of the vehicle it belongs to (:class:`sitl.vehicle.SimVehicle`)."""

    @property
    def cfg(self) -> SitlConfig: ...

    @property
    def status(self) -> FlightStatus: ...

    @property
    def params(self) -> ParamStore: ...

    @property
    def world(self) -> World: ...

    @property
    def dynamics(self) -> Dynamics: ...

    @property
    def controller(self) -> FlightController: ...

    @property
    def precland(self) -> LandingStart: ...

    @property
    def height_offset_m(self) -> float: ...

    @property
    def estimate(self) -> VehicleState: ...

    @property
    def home_ned_m(self) -> tuple[float, float, float]: ...

    @property
    def state(self) -> VehicleState: ...

    @property
    def time_s(self) -> float: ...

    def param(self, name: str) -> float: ...

    def say(self, severity: int, text: str) -> None: ...
