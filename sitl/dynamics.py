"""The simulated multirotor's flight dynamics: JSBSim's F450 quadrotor, commanded per motor.

The model is derived from the ``F450`` that the ``jsbsim`` package ships: its metrics, mass,
propulsion (four DJI E305 motors with 9450 propellers) and aerodynamics are loaded unchanged,
but its own flight control system and sensor models are left out (our cascade in
:mod:`sitl.control` replaces them and they cost a third of each step), and its ground contacts
are made fit for landings: four symmetric legs (the shipped three-point gear pitches the vehicle
up on every touchdown) soft enough for a stable contact at 126 Hz, skids instead of wheels, and
contact points at the arm tips and on top so that a vehicle that tips over rests on its frame
instead of sinking through the ground.

Motor order of ``step(esc)`` (PX4's quad X numbering, motors 1..4):
``(front right, aft left, front left, aft right)``; front right and aft left spin
counter-clockwise seen from above, front left and aft right clockwise.

``position_ned_m`` is local NED with its origin on the ground at home; its down axis is that of
the centre of gravity raised by the legs' length, so the vehicle standing on flat ground reads
``z = 0`` and standing on the roof of the ground vehicle reads ``z = -roof height``.

With a ``carrier`` that carries (``[sitl.world] roof_carries``) JSBSim flies in the frame of the
surface below, the driving roof's while over it (sitl/roof_frame.py); the state is the world's.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import jsbsim

from colcommon.errors import ConfigError, SimulatorError
from sitl.roof_frame import Carrier, RoofFrame, ned_to_body

FT_M = 0.3048
LBF_N = 4.4482216152605
GRAVITY_M_S2 = 9.80665

# PX4 SITL's default home (Zurich), so that ground stations show a familiar place.
HOME_LAT_DEG = 47.397742
HOME_LON_DEG = 8.545594
HOME_ALT_M = 488.0

GEAR_DEPTH_M = 0.1524  # the legs' contact points below the centre of gravity
MOTOR_ORDER = ("front_right", "aft_left", "front_left", "aft_right")
HOVER_THROTTLE = 0.416  # ESC command that holds the 1.4 kg F450 still in the air

_WGS84_A_M = 6378137.0
_WGS84_E2 = 6.69437999014e-3
_SIN2_LAT = math.sin(math.radians(HOME_LAT_DEG)) ** 2
_NORTH_M_PER_RAD = _WGS84_A_M * (1 - _WGS84_E2) / (1 - _WGS84_E2 * _SIN2_LAT) ** 1.5
_EAST_M_PER_RAD = (
    _WGS84_A_M / math.sqrt(1 - _WGS84_E2 * _SIN2_LAT) * math.cos(math.radians(HOME_LAT_DEG))
)
_HOME_LAT_RAD = math.radians(HOME_LAT_DEG)
_HOME_LON_RAD = math.radians(HOME_LON_DEG)

SPIN_UP_STEPS = 48  # FDM steps to bring the propellers to hover speed (or to a stop) on reset
SURFACE_TOLERANCE_M = 0.05  # a surface counts as "below" while the feet are above it minus this
SURFACE_MARGIN_M = 1.0  # above max_surface_height_m plus this, surfaces are not looked up
MIN_AIRBORNE_S = 0.5  # a contact after less flight than this is a bounce, not a touchdown
FRAME_FORCE = "carrying_frame"  # the external force of the frame JSBSim flies in (roof_carries)
POSITION_LAG_STEPS = 1.5  # JSBSim's positions take up a change of velocity this late (its trapezoidal
# position integrator, set in _load_f450): a frame switch moves the offset as late (sitl/roof_frame.py)

# Atmosphere (only with an Atmosphere set; see docs/sitl.md "Disturbances").
TURBULENCE_GROUND_ASL_M = 0.0  # JSBSim picks its turbulence model by height above sea level:
# near the ground of a 488 m home it would use its 1000-2000 ft blend (drifts over ~100 s); with
# JSBSim's ground at sea level it uses the low-altitude (< 1000 ft) model of a vehicle near it
TURBULENCE_SEVERITY = 3  # below 1000 ft it only switches the Milspec model on
TURBULENCE_PREROLL_S = 15.0  # the filters start at rest; run them this long (vehicle held) first
_MILSPEC = 3  # atmosphere/turb-type: MIL-F-8785C (Tustin, 4, can turn NaN after run_ic)
_PSF_PA = 47.880258889
_RANKINE_K = 1.8
_EARTH_RADIUS_M = 6356766.0  # JSBSim's, for the geopotential height of the standard atmosphere


def ned_to_geodetic(north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
    """Latitude, longitude (deg) and altitude above mean sea level (m) of a local NED point."""
    lat = HOME_LAT_DEG + math.degrees(north_m / _NORTH_M_PER_RAD)
    lon = HOME_LON_DEG + math.degrees(east_m / _EAST_M_PER_RAD)
    return lat, lon, HOME_ALT_M - down_m


def geodetic_to_ned(lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    """Inverse of :func:`ned_to_geodetic` (flat earth around home: exact to mm within km)."""
    north = math.radians(lat_deg - HOME_LAT_DEG) * _NORTH_M_PER_RAD
    east = math.radians(lon_deg - HOME_LON_DEG) * _EAST_M_PER_RAD
    return north, east, HOME_ALT_M - alt_m


def standard_atmosphere(height_asl_m: float) -> tuple[float, float]:
    """Pressure (Pa) and temperature (K) of the 1976 standard atmosphere below 11 km."""
    geopotential_m = _EARTH_RADIUS_M * height_asl_m / (_EARTH_RADIUS_M + height_asl_m)
    temperature_k = 288.15 - 0.0065 * geopotential_m
    return 101325.0 * (temperature_k / 288.15) ** 5.2558770, temperature_k


@dataclass(frozen=True)
class Atmosphere:
    """Steady wind (the air's NE velocity, m/s) and MIL-F-8785C turbulence (W20, m/s; 0 = none)
    with JSBSim's generator seed (1 .. 2^31 - 2; the same seed gives the same gusts)."""

    wind_ne_m_s: tuple[float, float] = (0.0, 0.0)
    turbulence_w20_m_s: float = 0.0
    seed: int = 1


@dataclass(frozen=True, slots=True)
class VehicleState:
    """True state of the vehicle at one instant (what sensors would measure, without noise)."""

    time_s: float
    position_ned_m: tuple[float, float, float]
    velocity_ned_m_s: tuple[float, float, float]
    attitude_rad: tuple[float, float, float]  # roll, pitch, yaw (yaw in (-pi, pi])
    rates_frd_rad_s: tuple[float, float, float]  # p, q, r body rates
    accel_frd_m_s2: tuple[float, float, float]  # specific force, as an IMU measures it
    on_ground: bool  # any leg or part of the frame touches a surface


@dataclass(frozen=True, slots=True)
class Contact:
    """The moment the vehicle met a surface after flying: where, when and how fast, in the world
    and relative to the surface it met (the driving roof's velocity is what a land detector and a
    "hard landing" judgement must take off: matching the pad's is a soft landing)."""

    time_s: float
    position_ned_m: tuple[float, float, float]
    velocity_ned_m_s: tuple[float, float, float]  # in the world, just before contact
    surface_velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)  # of the surface met then

    @property
    def speed_m_s(self) -> float:
        return math.sqrt(sum(v * v for v in self.velocity_ned_m_s))

    @property
    def relative_velocity_ned_m_s(self) -> tuple[float, float, float]:
        """The velocity just before contact relative to the surface it met."""
        v, s = self.velocity_ned_m_s, self.surface_velocity_ned_m_s
        return v[0] - s[0], v[1] - s[1], v[2] - s[2]

    @property
    def relative_speed_m_s(self) -> float:
        return math.sqrt(sum(v * v for v in self.relative_velocity_ned_m_s))


def flat_ground(north_m: float, east_m: float, t_s: float) -> float:
    """The default surface: open ground everywhere."""
    return 0.0


class Dynamics:
    """The F450 in JSBSim, stepped at ``fdm_rate_hz`` with four ESC commands in [0, 1].

    ``surface_height_m(north_m, east_m, t_s)`` gives the height of whatever is below a point
    (e.g. :meth:`sitl.world.World.surface_height_m`); JSBSim's terrain elevation follows it
    under the vehicle, so a roof is as solid as the ground. A surface higher than the vehicle's
    feet is not "below" it: the sides of obstacles are not modelled, only their tops.
    ``max_surface_height_m`` (optional) promises that no surface is higher: above it the
    lookup is skipped, which saves its cost in most of the flight.

    :attr:`last_contact` is the latest touchdown after at least ``MIN_AIRBORNE_S`` of flight
    (bounces do not replace it); ``reset`` clears it. ``carrier`` (the world's ground vehicle)
    gives a contact on its roof the roof's velocity; with ``carries`` the roof is solid for the
    legs' friction too and carries what stands on it: JSBSim then flies in the frame of the
    surface below (sitl/roof_frame.py). Without ``carries`` not one float operation of a step
    changes.

    ``ground_asl_m`` is where JSBSim puts the local ground (the reported home stays at
    ``HOME_ALT_M``); away from it the air is made as dense and warm as at ``HOME_ALT_M``, so
    only the turbulence model sees the difference. :meth:`set_atmosphere` adds wind and
    turbulence from the next :meth:`reset` on.
    """

    def __init__(
        self,
        fdm_rate_hz: float = 126.0,
        surface_height_m: Callable[[float, float, float], float] | None = None,
        max_surface_height_m: float = math.inf,
        ground_asl_m: float = HOME_ALT_M,
        carrier: Carrier | None = None,
        carries: bool = False,
    ) -> None:
        if not (math.isfinite(fdm_rate_hz) and 60.0 <= fdm_rate_hz <= 1000.0):
            raise ConfigError(f"fdm_rate_hz={fdm_rate_hz!r}: use a rate between 60 and 1000 Hz")
        if carries and carrier is None:
            raise ConfigError("carries needs the carrier (the world's ground vehicle) whose roof carries")
        self.dt_s = 1.0 / fdm_rate_hz
        self.home_lat_deg = HOME_LAT_DEG
        self.home_lon_deg = HOME_LON_DEG
        self.home_alt_m = HOME_ALT_M
        self._surface = surface_height_m or flat_ground
        self._lookup_below_down_m = -(max_surface_height_m + SURFACE_MARGIN_M)
        self._min_airborne_steps = math.ceil(MIN_AIRBORNE_S * fdm_rate_hz)
        self._airborne_steps = 0
        self._ground_asl_m = float(ground_asl_m)
        self._atmosphere: Atmosphere | None = None
        self._carrier = carrier
        self._frame = RoofFrame(carrier) if carries and carrier is not None else None
        self._fdm = _load_f450(self.dt_s, frame_force=self._frame is not None)
        if self._ground_asl_m != HOME_ALT_M:
            self._air_as_at_home()
        self._bind_properties()
        if self._frame is not None:
            self._bind_frame_force()
        self._time_base_s = 0.0
        self._steps = 0
        self._terrain_m = 0.0
        self.last_contact: Contact | None = None
        self._state = self.reset((0.0, 0.0, 0.0), time_s=0.0)

    def _bind_properties(self) -> None:
        """Bound accessors of the few JSBSim properties a step needs (a lookup by name costs)."""
        node = self._node
        self._set_throttle = tuple(
            node(f"fcs/throttle-cmd-norm[{i}]").set_double_value for i in range(4)
        )
        self._set_terrain_ft = node("position/terrain-elevation-asl-ft").set_double_value
        names = (
            "position/lat-geod-rad position/long-gc-rad position/h-sl-meters "
            "velocities/v-north-fps velocities/v-east-fps velocities/v-down-fps "
            "attitude/phi-rad attitude/theta-rad attitude/psi-rad "
            "velocities/p-rad_sec velocities/q-rad_sec velocities/r-rad_sec "
            "accelerations/a-pilot-x-ft_sec2 accelerations/a-pilot-y-ft_sec2 "
            "accelerations/a-pilot-z-ft_sec2 gear/wow forces/fbz-gear-lbs"
        ).split()
        self._getters = tuple(node(n).get_double_value for n in names)

    def _node(self, name: str) -> jsbsim.FGPropertyNode:
        found = self._fdm.get_property_manager().get_node(name)
        if found is None:
            raise SimulatorError(f"JSBSim has no property {name}; use jsbsim 1.3.x")
        return found

    def _bind_frame_force(self) -> None:
        """The frame force's setters, the force at the centre of gravity (no moment), and the
        mass it scales with (constant: the F450 burns no fuel)."""
        fdm = self._fdm
        for axis in "xyz":
            fdm[f"external_reactions/{FRAME_FORCE}/location-{axis}-in"] = fdm[f"inertia/cg-{axis}-in"]
        fdm[f"external_reactions/{FRAME_FORCE}/magnitude"] = 1.0  # the direction is the force in lbf
        self._set_force_lbf = tuple(self._node(f"external_reactions/{FRAME_FORCE}/{axis}").set_double_value for axis in "xy")
        self._mass_slugs = fdm["inertia/mass-slugs"]
        self._force_accel_ne = (0.0, 0.0)
        self._frame_velocity_next = (0.0, 0.0)

    def _air_as_at_home(self) -> None:
        """Sea-level pressure and a temperature offset that give the ground the air of HOME_ALT_M."""
        p_home, t_home = standard_atmosphere(HOME_ALT_M)
        p_ground, t_ground = standard_atmosphere(self._ground_asl_m)
        p_sl, _ = standard_atmosphere(0.0)
        self._fdm["atmosphere/P-sl-psf"] = p_sl * p_home / p_ground / _PSF_PA
        self._fdm["atmosphere/delta-T"] = (t_home - t_ground) * _RANKINE_K

    @property
    def state(self) -> VehicleState:
        return self._state

    @property
    def time_s(self) -> float:
        return self._time_base_s + self._steps * self.dt_s

    @property
    def steps(self) -> int:
        """FDM steps since the last reset."""
        return self._steps

    def set_atmosphere(self, atmosphere: Atmosphere | None) -> None:
        """Wind and turbulence from the next :meth:`reset` on (None: calm, the default)."""
        self._atmosphere = atmosphere

    def wind_ned_m_s(self) -> tuple[float, float, float]:
        """The air's velocity at the vehicle now: steady wind plus turbulence."""
        wind = tuple(self._fdm[f"atmosphere/total-wind-{axis}-fps"] * FT_M for axis in ("north", "east", "down"))
        if self._frame is not None:  # JSBSim's air is relative to the frame it flies in
            fn, fe = self._frame.velocity_ne
            return wind[0] + fn, wind[1] + fe, wind[2]
        return wind  # type: ignore[return-value]

    @property
    def carried_velocity_ne_m_s(self) -> tuple[float, float]:
        """The velocity of the surface whose frame JSBSim flies in (the roof's while over it; zero
        on the ground or without ``carries``): what a velocity relative to the surface subtracts."""
        return (0.0, 0.0) if self._frame is None else self._frame.velocity_ne

    def reset(
        self,
        position_ned_m: tuple[float, float, float],
        yaw_rad: float = 0.0,
        velocity_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        time_s: float | None = None,
    ) -> VehicleState:
        """Place the vehicle level at a pose, hovering in the air or at rest on a surface.

        A position below the surface under it is lifted onto that surface. In the air the
        propellers already turn at hover speed; on a surface they stand still.
        """
        values = (*position_ned_m, yaw_rad, *velocity_ned_m_s)
        if len(values) != 7 or not all(math.isfinite(v) for v in values):
            raise SimulatorError(
                f"reset needs a finite 3D position, yaw and 3D velocity; got "
                f"position={position_ned_m!r}, yaw={yaw_rad!r}, velocity={velocity_ned_m_s!r}"
            )
        self._time_base_s = self.time_s if time_s is None else float(time_s)
        self._steps = 0
        north, east, down = (float(v) for v in position_ned_m)
        surface = float(self._surface(north, east, self._time_base_s))
        on_surface = -down <= surface + 1e-3
        if on_surface:
            down, velocity_ned_m_s = -surface, (0.0, 0.0, 0.0)
        self._terrain_m = surface
        self._initial = (north, east, down, float(yaw_rad), *map(float, velocity_ned_m_s))
        if self._frame is not None:
            self._start_frame(on_surface)
        throttle = 0.0 if on_surface else HOVER_THROTTLE
        self._apply_initial_conditions()
        for set_throttle in self._set_throttle:
            set_throttle(throttle)
        if self._atmosphere is None:
            if self._frame is not None:
                self._set_wind(None)  # the air moves in the roof's frame
            for _ in range(SPIN_UP_STEPS):  # propellers keep their speed across run_ic
                self._fdm.run()
            self._apply_initial_conditions()
            if self._frame is not None:
                self._set_wind(None)
        else:
            self._preroll_atmosphere(self._atmosphere)
            self._apply_initial_conditions()
            self._set_wind(self._atmosphere)  # run_ic zeroes the steady wind
        self.last_contact = None
        self._airborne_steps = 0 if on_surface else self._min_airborne_steps
        self._state = self._read_state() if self._frame is None else self._world_state(self._read_state())
        return self._state

    def _start_frame(self, on_surface: bool) -> None:
        """Fly in the frame of the surface below from the reset on: JSBSim's position is the
        world's now, its velocity relative to that surface (zero: standing on it)."""
        frame = self._frame
        assert frame is not None and self._carrier is not None
        north, east, down, yaw, vn, ve, vd = self._initial
        frame.start(self._carrier.over_roof(north, east, self._time_base_s), self._time_base_s)
        fn, fe = frame.velocity_ne
        self._initial = (north, east, down, yaw, *((0.0, 0.0, 0.0) if on_surface else (vn - fn, ve - fe, vd)))
        self._push_frame_for(self._time_base_s + self.dt_s)  # before run_ic, which takes the first forces

    def _apply_initial_conditions(self) -> None:
        north, east, down, yaw, vn, ve, vd = self._initial
        lat, lon, _ = ned_to_geodetic(north, east, down)
        fdm = self._fdm
        fdm["ic/lat-geod-deg"] = lat
        fdm["ic/long-gc-deg"] = lon
        fdm["ic/terrain-elevation-ft"] = (self._ground_asl_m + self._terrain_m) / FT_M
        fdm["ic/h-sl-ft"] = (self._ground_asl_m - down + GEAR_DEPTH_M) / FT_M
        fdm["ic/psi-true-rad"] = yaw % (2 * math.pi)
        fdm["ic/phi-rad"] = 0.0
        fdm["ic/theta-rad"] = 0.0
        for name, value in (("vn", vn), ("ve", ve), ("vd", vd)):
            fdm[f"ic/{name}-fps"] = value / FT_M
        for name in ("p", "q", "r"):
            fdm[f"ic/{name}-rad_sec"] = 0.0
        fdm.run_ic()

    def _preroll_atmosphere(self, atm: Atmosphere) -> None:
        """Seed and switch on the turbulence, then run the model with the vehicle held in place
        (it spins up its propellers meanwhile) until the gusts have their full strength; the
        filters' states survive the run_ic that follows."""
        fdm = self._fdm
        fdm["atmosphere/randomseed"] = atm.seed
        fdm["atmosphere/turb-type"] = _MILSPEC
        fdm["atmosphere/turbulence/milspec/windspeed_at_20ft_AGL-fps"] = atm.turbulence_w20_m_s / FT_M
        fdm["atmosphere/turbulence/milspec/severity"] = TURBULENCE_SEVERITY if atm.turbulence_w20_m_s > 0 else 0
        self._set_wind(atm)
        steps = SPIN_UP_STEPS
        if atm.turbulence_w20_m_s > 0:
            steps = max(steps, math.ceil(TURBULENCE_PREROLL_S / self.dt_s))
        fdm["forces/hold-down"] = 1
        for _ in range(steps):
            fdm.run()
        fdm["forces/hold-down"] = 0

    def _set_wind(self, atm: Atmosphere | None) -> None:
        """The steady wind JSBSim blows: the atmosphere's (calm: None), relative to the frame."""
        north, east = (0.0, 0.0) if atm is None else atm.wind_ne_m_s
        if self._frame is not None:
            fn, fe = self._frame.velocity_ne
            north, east = north - fn, east - fe
        if north == 0.0 and east != 0.0:
            north = 1e-6  # JSBSim keeps the wind's direction at 0 while its north part is 0
        self._fdm["atmosphere/wind-north-fps"] = north / FT_M
        self._fdm["atmosphere/wind-east-fps"] = east / FT_M
        self._fdm["atmosphere/wind-down-fps"] = 0.0

    def step(self, esc: tuple[float, float, float, float]) -> VehicleState:
        """Advance one FDM step with ESC commands (MOTOR_ORDER), each clipped to [0, 1].

        A non-finite command counts as 0 (motor off): it never reaches JSBSim.
        """
        e0, e1, e2, e3 = esc
        s0, s1, s2, s3 = self._set_throttle
        # clip to [0, 1] inline (hot path); NaN fails both tests and becomes 0
        s0(e0 if 0.0 < e0 < 1.0 else 1.0 if e0 >= 1.0 else 0.0)
        s1(e1 if 0.0 < e1 < 1.0 else 1.0 if e1 >= 1.0 else 0.0)
        s2(e2 if 0.0 < e2 < 1.0 else 1.0 if e2 >= 1.0 else 0.0)
        s3(e3 if 0.0 < e3 < 1.0 else 1.0 if e3 >= 1.0 else 0.0)
        prev = self._state
        if self._frame is None:
            north, east, down = prev.position_ned_m
            if down > self._lookup_below_down_m:
                self._follow_surface(self._surface(north, east, prev.time_s), down)
            self._fdm.run()
            self._steps += 1
            state = self._read_state()
        else:
            state = self._step_carried(prev)
        if not state.on_ground:
            self._airborne_steps += 1
        elif not prev.on_ground:
            if self._airborne_steps >= self._min_airborne_steps:
                self.last_contact = Contact(
                    state.time_s, state.position_ned_m, prev.velocity_ned_m_s, self._met_surface_velocity(state, prev.time_s)
                )
            self._airborne_steps = 0
        self._state = state
        return state

    def _met_surface_velocity(self, contact: VehicleState, before_s: float) -> tuple[float, float, float]:
        """The velocity at ``before_s`` (the step before the contact) of the surface a contact
        met: the roof's if it met the roof, else the ground's, zero."""
        carrier = self._carrier
        if carrier is None:
            return 0.0, 0.0, 0.0
        if self._frame is not None:
            on_roof = self._frame.on_roof
        else:
            north, east, _ = contact.position_ned_m
            on_roof = self._terrain_m == carrier.roof_height_m and carrier.over_roof(north, east, contact.time_s)
        if not on_roof:
            return 0.0, 0.0, 0.0
        vn, ve = carrier.velocity_at(before_s)
        return float(vn), float(ve), 0.0

    def _step_carried(self, prev: VehicleState) -> VehicleState:
        """One step in the frame of the surface below.

        A JSBSim step integrates the forces it took at the end of the step before, and takes the
        next ones at its end: the frame force set now acts over the next step, so it is set for
        the change of the frame's velocity from this step's end to the next one's; JSBSim's
        velocity at this step's end is relative to the frame velocity the force set in the step
        before aimed at (``_frame_velocity_next``).
        """
        frame = self._frame
        assert frame is not None
        end_s = self._time_base_s + (self._steps + 1) * self.dt_s
        north, east, down = prev.position_ned_m
        if down > self._lookup_below_down_m:
            self._follow_carrier(north, east, down, prev.time_s, end_s)
        if self._frame_velocity_next != frame.velocity_ne:
            frame.velocity_ne = self._frame_velocity_next
            self._set_wind(self._atmosphere)  # the forces at the step's end take the air relative to it
        acted_ne = self._force_accel_ne
        self._push_frame_for(end_s + self.dt_s)
        self._fdm.run()
        self._steps += 1
        return self._world_state(self._read_state(), acted_ne, prev.attitude_rad)

    def _push_frame_for(self, next_end_s: float) -> None:
        """The frame force over the next step: its velocity from ``velocity_ne`` to that at
        ``next_end_s``."""
        frame = self._frame
        assert frame is not None
        un, ue = frame.velocity_ne
        vn, ve = frame.velocity_at(next_end_s)
        self._push_frame((vn - un) / self.dt_s, (ve - ue) / self.dt_s)
        self._frame_velocity_next = (vn, ve)

    def _follow_carrier(self, north_m: float, east_m: float, down_m: float, t_s: float, end_s: float) -> None:
        """:meth:`_follow_surface` at ``t_s``, and the frame of that surface from ``end_s`` on
        (when the frame force can first act): a switch between ground and roof happens only when
        the surface below changes, i.e. in flight."""
        surface_m = self._surface(north_m, east_m, t_s)
        if surface_m > SURFACE_TOLERANCE_M - down_m:
            return  # above the feet: not below (the sides of the ground vehicle are not modelled)
        self._follow_surface(surface_m, down_m)
        frame = self._frame
        assert frame is not None
        on_roof = frame.carrier.over_roof(north_m, east_m, t_s)
        if on_roof != frame.on_roof:
            frame.switch(on_roof, end_s, POSITION_LAG_STEPS * self.dt_s)

    def _push_frame(self, accel_n_m_s2: float, accel_e_m_s2: float) -> None:
        """The force of the accelerating frame on the vehicle: -mass x its acceleration."""
        if (accel_n_m_s2, accel_e_m_s2) == self._force_accel_ne:
            return
        self._force_accel_ne = (accel_n_m_s2, accel_e_m_s2)
        set_n, set_e = self._set_force_lbf
        set_n(-self._mass_slugs * accel_n_m_s2 / FT_M)
        set_e(-self._mass_slugs * accel_e_m_s2 / FT_M)

    def _world_state(self, state: VehicleState, accel_ne_m_s2: tuple[float, float] = (0.0, 0.0),
                     attitude_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> VehicleState:
        """JSBSim's state in the frame made the world's: moved by the frame's offset, its velocity
        added, and the frame force taken out of the specific force (``accel_ne_m_s2``, the frame's
        acceleration over the step, in the body axes of ``attitude_rad`` at its start, where
        JSBSim took its forces)."""
        frame = self._frame
        assert frame is not None
        off_n, off_e = frame.offset_ne(state.time_s)
        fn, fe = frame.velocity_ne
        n, e, d = state.position_ned_m
        vn, ve, vd = state.velocity_ned_m_s
        ax, ay, az = state.accel_frd_m_s2
        if accel_ne_m_s2 != (0.0, 0.0):
            bx, by, bz = ned_to_body((*accel_ne_m_s2, 0.0), attitude_rad)
            ax, ay, az = ax + bx, ay + by, az + bz
        return VehicleState(state.time_s, (n + off_n, e + off_e, d), (vn + fn, ve + fe, vd), state.attitude_rad,
                            state.rates_frd_rad_s, (ax, ay, az), state.on_ground)

    def _follow_surface(self, surface_m: float, down_m: float) -> None:
        """Move JSBSim's terrain to the surface below, unless that is above the feet."""
        if surface_m != self._terrain_m and surface_m <= SURFACE_TOLERANCE_M - down_m:
            self._terrain_m = surface_m
            self._set_terrain_ft((self._ground_asl_m + surface_m) / FT_M)

    def _read_state(self) -> VehicleState:
        (lat, lon, h, vn, ve, vd, phi, theta, psi, p, q, r, ax, ay, az, wow, fz) = [
            get() for get in self._getters
        ]
        return VehicleState(
            self._time_base_s + self._steps * self.dt_s,
            (
                (lat - _HOME_LAT_RAD) * _NORTH_M_PER_RAD,
                (lon - _HOME_LON_RAD) * _EAST_M_PER_RAD,
                self._ground_asl_m + GEAR_DEPTH_M - h,
            ),
            (vn * FT_M, ve * FT_M, vd * FT_M),
            (phi, theta, psi - 2 * math.pi if psi > math.pi else psi),
            (p, q, r),
            (ax * FT_M, ay * FT_M, az * FT_M),
            wow > 0.0 or fz != 0.0,
        )


class SilentLogger(jsbsim.FGLogger):
    """Swallows JSBSim's console chatter; real failures still raise exceptions."""

    def set_level(self, level: jsbsim.LogLevel) -> None:
        pass

    def file_location(self, filename: str, line: int) -> None:
        pass

    def message(self, message: str) -> None:
        pass

    def format(self, format: jsbsim.LogFormat) -> None:
        pass

    def flush(self) -> None:
        pass


_TOP_XML = """<?xml version="1.0"?>
<fdm_config name="F450" version="2.0" release="ALPHA">
  <fileheader><description>JSBSim's F450 without its FCS and sensors, with landing contacts
  (derived by sitl/dynamics.py)</description></fileheader>
  <metrics file="Metrics.xml"/>
  <mass_balance file="Mass.xml"/>
  <ground_reactions file="Gear.xml"/>
  <propulsion file="Propulsion.xml"/>
  <aerodynamics file="Aero.xml"/>
</fdm_config>
"""

# (name, type, x, y, z) in JSBSim's structural frame (x aft, y right, z up; metres from the CG).
_CONTACTS = (
    ("Front_Left", "BOGEY", -0.1016, -0.1016, -GEAR_DEPTH_M),
    ("Front_Right", "BOGEY", -0.1016, 0.1016, -GEAR_DEPTH_M),
    ("Aft_Left", "BOGEY", 0.1016, -0.1016, -GEAR_DEPTH_M),
    ("Aft_Right", "BOGEY", 0.1016, 0.1016, -GEAR_DEPTH_M),
    ("Arm_Front_Right", "STRUCTURE", -0.1651, 0.1651, 0.025),
    ("Arm_Aft_Left", "STRUCTURE", 0.1651, -0.1651, 0.025),
    ("Arm_Front_Left", "STRUCTURE", -0.1651, -0.1651, 0.025),
    ("Arm_Aft_Right", "STRUCTURE", 0.1651, 0.1651, 0.025),
    ("Top", "STRUCTURE", 0.0, 0.0, 0.06),
)
# Stiffness and damping that stay stable with one leg touching at 126 Hz (the shipped 3000 N/m
# and 100 N/(m/s) launch the vehicle on a tilted 1 m/s touchdown); ~2.5 mm static compression.
_SPRING_N_M = 1000.0
_DAMPING_N_M_S = 40.0


def _gear_xml() -> str:
    contacts = "".join(
        f'  <contact name="{name}" type="{kind}">\n'
        f'    <location unit="M"><x>{x}</x><y>{y}</y><z>{z}</z></location>\n'
        "    <static_friction>0.8</static_friction><dynamic_friction>0.5</dynamic_friction>\n"
        "    <rolling_friction>0.5</rolling_friction>\n"
        f'    <spring_coeff unit="N/M">{_SPRING_N_M}</spring_coeff>\n'
        f'    <damping_coeff unit="N/M/SEC">{_DAMPING_N_M_S}</damping_coeff>\n'
        "  </contact>\n"
        for name, kind, x, y, z in _CONTACTS
    )
    return f'<?xml version="1.0"?>\n<ground_reactions>\n{contacts}</ground_reactions>\n'


def _top_xml(frame_force: bool) -> str:
    """The aircraft file; with ``frame_force`` an external force (LOCAL frame: north, east, down)
    for the carrying frame's acceleration. Without it, the file is the one results were made with."""
    if not frame_force:
        return _TOP_XML
    force = (f'  <external_reactions>\n    <force name="{FRAME_FORCE}" frame="LOCAL" unit="LBS">\n'
             '      <location unit="M"><x>0</x><y>0</y><z>0</z></location>\n'
             '      <direction><x>0</x><y>0</y><z>0</z></direction>\n    </force>\n  </external_reactions>\n')
    return _TOP_XML.replace("</fdm_config>", force + "</fdm_config>")


def _load_f450(dt_s: float, frame_force: bool = False) -> jsbsim.FGFDMExec:
    """A quiet JSBSim executive holding the derived F450, with integrators stable on contact
    (and with ``frame_force``, the carrying frame's force: sitl/roof_frame.py)."""
    jsbsim.set_logger(SilentLogger())
    root = Path(jsbsim.get_default_root_dir())
    shipped = root / "aircraft" / "F450"
    fdm = jsbsim.FGFDMExec(str(root))
    fdm.set_debug_level(0)
    with tempfile.TemporaryDirectory(prefix="col-f450-") as tmp:
        model_dir = Path(tmp) / "F450"
        model_dir.mkdir()
        for name in ("Metrics.xml", "Mass.xml", "Propulsion.xml", "Aero.xml"):
            shutil.copyfile(shipped / name, model_dir / name)
        (model_dir / "F450.xml").write_text(_top_xml(frame_force))
        (model_dir / "Gear.xml").write_text(_gear_xml())
        if not fdm.load_model_with_paths("F450", tmp, str(root / "engine"), str(root / "systems")):
            raise SimulatorError(
                "JSBSim could not load the F450 model; reinstall the jsbsim package (1.3.x)"
            )
    fdm.set_dt(dt_s)
    # Euler rates + trapezoidal positions: the shipped Adams-Bashforth defaults are unstable on
    # the legs' contact at this step size; flight itself is unaffected.
    for name, value in (
        ("rate/rotational", 1),
        ("rate/translational", 1),
        ("position/rotational", 2),
        ("position/translational", 2),
    ):
        fdm[f"simulation/integrator/{name}"] = value
    for model in ("FGInput", "FGOutput", "FGBuoyantForces", "FGExternalReactions"):
        fdm[f"simulation/models/{model}/enabled"] = 0
    if frame_force:
        fdm["simulation/models/FGExternalReactions/enabled"] = 1
    return fdm
