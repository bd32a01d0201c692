"""The vehicle snapshot: everything known about the vehicle at one instant, as the link folds
its messages (companion/link/)."""

from __future__ import annotations

from dataclasses import dataclass

from companion.msg.true_pose import TruePose

Vec3 = tuple[float, float, float]

LANDED_STATES = ("UNDEFINED", "ON_GROUND", "IN_AIR", "TAKEOFF", "LANDING")


@dataclass(frozen=True)
class VehicleSnapshot:
    """Everything known about the vehicle at one instant; replaced whole on every update."""

    received_s: float  # monotonic time of the newest message folded in
    time_boot_ms: int  # the vehicle's clock, from its newest timestamped message (of any kind)
    frame_time_boot_ms: int | None  # newest frame marker (SYSTEM_TIME in lockstep), if any
    system_id: int
    autopilot: str  # "PX4", "ARDUPILOTMEGA", ...
    armed: bool
    mode: str  # the autopilot's name: PX4 "OFFBOARD", "AUTO.LOITER"; ArduPilot "GUIDED", "BRAKE"
    landed_state: str  # one of LANDED_STATES
    position_ned_m: Vec3
    velocity_ned_m_s: Vec3
    attitude_rad: Vec3  # roll, pitch, yaw
    rates_frd_rad_s: Vec3  # roll rate, pitch rate, yaw rate
    heartbeat_s: float  # monotonic time of the newest HEARTBEAT
    position_valid: bool = False  # a position message has arrived
    attitude_valid: bool = False  # an attitude message has arrived
    home_ned_m: Vec3 | None = None
    """Home in the vehicle's local frame (HOME_POSITION x, y, z; None until one arrives). On
    PX4 the local origin is where the estimator started, not the ground: heights are taken
    from here (companion/link/home.py), never from z = 0."""
    ground_distance_m: float | None = None
    """A downward rangefinder's reading (DISTANCE_SENSOR, orientation down), metres to the surface
    below; None when there is none or its reading is out of its range (PX4 SIH has one)."""
    ground_distance_s: float = 0.0  # monotonic time of that reading
    truth_lat_lon_deg: tuple[float, float] | None = None
    """A simulator's true position, where the autopilot's SITL sends one (PX4 SIH:
    HIL_STATE_QUATERNION; ArduPilot: SIMSTATE or SIM_STATE); never on a real vehicle."""
    origin_lat_lon_deg: tuple[float, float] | None = None
    """Where the local frame's origin is (GPS_GLOBAL_ORIGIN), to put the pad on the true map."""
    position_time_boot_ms: int | None = None
    """The vehicle's own stamp of the position and velocity held here (LOCAL_POSITION_NED's
    time_boot_ms; None until one arrives): what says whether a control step's observation is
    newer than the last one's (companion/control/freshness.py), not its arrival."""
    attitude_time_boot_ms: int | None = None
    """The vehicle's own stamp of the attitude and rates held here (ATTITUDE's time_boot_ms)."""
    origin_alt_m: float | None = None
    """The local origin's altitude (GPS_GLOBAL_ORIGIN, metres AMSL): true heights are taken from it."""
    true_pose: TruePose | None = None
    """The simulator's true pose in the local frame (companion/link/truth.py), where the
    autopilot's SITL sends one and the local origin is known; never on a real vehicle."""

    @property
    def in_air(self) -> bool:
        return self.landed_state in ("IN_AIR", "TAKEOFF", "LANDING")
