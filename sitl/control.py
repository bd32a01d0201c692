"""The simulated autopilot's flight control cascade, as in PX4's multicopter stack.

position P -> velocity PI -> desired acceleration -> roll/pitch (tilt-limited) and collective
thrust (hover- and tilt-compensated) -> attitude P -> body-rate PID -> quad-X mixer -> ESCs.

Everything runs at the FDM rate on plain floats: this loop and the FDM step must together run
hundreds of times faster than real time.

Mixer (motor order of :mod:`sitl.dynamics`, PX4's quad X): ``(front right, aft left,
front left, aft right)``; a positive roll/pitch/yaw command is a positive torque about the body
x (right wing down) / y (nose up) / z (nose right) axis:

==========  ====  =====  ===
motor       roll  pitch  yaw
==========  ====  =====  ===
front right  -1    +1    +1  (spins counter-clockwise)
aft left     +1    -1    +1  (counter-clockwise)
front left   +1    +1    -1  (clockwise)
aft right    -1    -1    -1  (clockwise)
==========  ====  =====  ===
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.config import AutopilotConfig
from sitl.dynamics import GRAVITY_M_S2, VehicleState

NAN = math.nan
NAN3 = (NAN, NAN, NAN)
# each motor's share of a roll, pitch, yaw command (the table above; mix() spells it out)
MOTOR_ROLL = (-1.0, 1.0, 1.0, -1.0)
MOTOR_PITCH = (1.0, -1.0, 1.0, -1.0)
MOTOR_YAW = (1.0, 1.0, -1.0, -1.0)
ESC_OFF = (0.0, 0.0, 0.0, 0.0)
MIN_LIFT_RATIO = 0.25  # never ask for less than this fraction of weight: keeps control authority
MAX_LIFT_RATIO = 2.5
_MIN_LIFT = MIN_LIFT_RATIO * GRAVITY_M_S2
_MAX_LIFT = MAX_LIFT_RATIO * GRAVITY_M_S2
_IDLE_ACCEL = (0.0, 0.0, GRAVITY_M_S2)  # falling freely: the least lift the cascade asks for
TAKEOFF_CLIMB_M_S = 0.3  # PX4's FlightTask::_checkTakeoff: a climb setpoint faster than this,
TAKEOFF_HEIGHT_M = 0.2  # or a position setpoint this much higher, asks a landed vehicle to go


@dataclass(frozen=True, slots=True)
class Setpoint:
    """What the vehicle should do; a NaN component means "not controlled on this axis".

    Per NED axis: position if set (velocity then acts as feed-forward), else velocity, else
    hold velocity 0. Heading: yaw if set, else yaw rate, else hold (rate 0).
    """

    position_ned_m: tuple[float, float, float] = NAN3
    velocity_ned_m_s: tuple[float, float, float] = NAN3
    yaw_rad: float = NAN
    yaw_rate_rad_s: float = NAN

    def __post_init__(self) -> None:
        if len(self.position_ned_m) != 3 or len(self.velocity_ned_m_s) != 3:
            raise ValueError("Setpoint position and velocity must have 3 components (N, E, D)")


HOLD = Setpoint()


def _finite(x: float, default: float) -> float:
    return x if x - x == 0.0 else default  # NaN and +-inf fail x - x == 0


def _clamp(x: float, low: float, high: float) -> float:
    return low if x < low else high if x > high else x


def _wrap_pi(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def mix(
    collective: float, roll: float, pitch: float, yaw: float
) -> tuple[float, float, float, float]:
    """Quad-X mixer with saturation handling: attitude first, then thrust, then yaw.

    Roll and pitch are scaled down together if their spread alone exceeds the ESC range;
    the collective is then shifted so no motor leaves [0, 1]; yaw gets what room is left.
    """
    d0, d1, d2, d3 = -roll + pitch, roll - pitch, roll + pitch, -roll - pitch
    spread = max(d0, d1, d2, d3) - min(d0, d1, d2, d3)
    if spread > 1.0:
        d0, d1, d2, d3 = d0 / spread, d1 / spread, d2 / spread, d3 / spread
    low, high = -min(d0, d1, d2, d3), 1.0 - max(d0, d1, d2, d3)
    t = _clamp(collective, low, high)
    m0, m1, m2, m3 = t + d0, t + d1, t + d2, t + d3
    # yaw adds to m0, m1 and subtracts from m2, m3: keep all four within [0, 1]
    yaw = _clamp(yaw, max(-m0, -m1, m2 - 1.0, m3 - 1.0), min(1.0 - m0, 1.0 - m1, m2, m3))
    return m0 + yaw, m1 + yaw, m2 - yaw, m3 - yaw


def throttle_for_lift(lift_ratio: float, hover_throttle: float, quadratic: float) -> float:
    """ESC command whose thrust is ``lift_ratio`` times the weight.

    Thrust curve model: ratio = q x^2 + (1 - q) x with x = throttle / hover_throttle.
    """
    q = quadratic
    x = (math.sqrt((1.0 - q) ** 2 + 4.0 * q * lift_ratio) - (1.0 - q)) / (2.0 * q)
    return x * hover_throttle


@dataclass(frozen=True, slots=True)
class _Gains:
    """The config's gains and limits as plain slots (read ~40 times a step: pydantic is slower)."""

    pos_p_xy: float
    pos_p_z: float
    max_xy_m_s: float
    max_up_m_s: float
    max_down_m_s: float
    vel_p_xy: float
    vel_i_xy_dt: float
    vel_i_max_xy: float
    vel_p_z: float
    vel_i_z_dt: float
    vel_i_max_z: float
    vel_i_zone2: float
    tan_tilt: float
    hover_throttle: float
    thrust_quadratic: float
    att_p_rp: float
    att_p_yaw: float
    max_rate_rp: float
    max_yaw_rate: float
    rate_p_rp: float
    rate_i_rp_dt: float
    rate_d_rp_per_dt: float
    rate_i_max: float
    rate_p_yaw: float
    rate_i_yaw_dt: float
    rate_i_max_yaw: float
    vel_cmd_blend: float  # share of the new horizontal velocity command taken each step (1: no lag)

    @classmethod
    def from_config(cls, cfg: AutopilotConfig, dt_s: float) -> _Gains:
        return cls(
            cfg.pos_p_xy,
            cfg.pos_p_z,
            cfg.max_speed_xy_m_s,
            cfg.max_speed_up_m_s,
            cfg.max_speed_down_m_s,
            cfg.vel_p_xy,
            cfg.vel_i_xy * dt_s,
            cfg.vel_i_max_xy_m_s2,
            cfg.vel_p_z,
            cfg.vel_i_z * dt_s,
            cfg.vel_i_max_z_m_s2,
            cfg.vel_i_zone_m_s**2,
            math.tan(cfg.max_tilt_rad),
            cfg.hover_throttle,
            cfg.thrust_curve_quadratic,
            cfg.att_p_rp,
            cfg.att_p_yaw,
            cfg.max_rate_rp_rad_s,
            cfg.max_yaw_rate_rad_s,
            cfg.rate_p_rp,
            cfg.rate_i_rp * dt_s,
            cfg.rate_d_rp / dt_s,
            cfg.rate_i_max,
            cfg.rate_p_yaw,
            cfg.rate_i_yaw * dt_s,
            cfg.rate_i_max_yaw,
            1.0 - math.exp(-dt_s / cfg.vel_cmd_tau_s) if cfg.vel_cmd_tau_s > 0 else 1.0,
        )


class FlightController:
    """The cascade, from a :class:`Setpoint` to four ESC commands, at a fixed step ``dt_s``.

    Runs on every FDM step, so it is written for speed: plain floats, gains in slots, clamps
    inlined (``lo if x < lo else hi if x > hi else x``).
    """

    def __init__(self, cfg: AutopilotConfig, dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"dt_s={dt_s!r}: the controller needs a positive, finite time step")
        self.cfg = cfg
        self.dt_s = dt_s
        self._g = _Gains.from_config(cfg, dt_s)
        self.reset()

    def configure(self, cfg: AutopilotConfig) -> None:
        """New limits and gains (a parameter changed in flight); integrators are kept."""
        self.cfg = cfg
        self._g = _Gains.from_config(cfg, self.dt_s)

    def reset(self) -> None:
        """Forget integrators and filter memory (on arming, mode changes, resets)."""
        self._vel_int = [0.0, 0.0, 0.0]
        self._rate_int = [0.0, 0.0, 0.0]
        self._prev_rates = (0.0, 0.0, 0.0)
        self._lagged_xy: tuple[float, float] | None = None  # the lagged horizontal velocity command
        self.lift_ratio = 1.0  # last collective thrust asked for, as a fraction of weight
        self.collective = 0.0  # last collective ESC command (before mixing)

    def update(
        self, state: VehicleState, sp: Setpoint, armed: bool
    ) -> tuple[float, float, float, float]:
        """ESC commands for this step; all zero when disarmed."""
        if not armed:
            self.reset()
            return ESC_OFF
        vel_cmd = self._velocity_command(state, sp)
        accel = self._acceleration(state, vel_cmd)
        roll_sp, pitch_sp, collective = self._attitude_and_thrust(state, accel)
        rates_sp = self._rates(state, roll_sp, pitch_sp, self._yaw_rate(state, sp))
        torque = self._rate_loop(state, rates_sp)
        return mix(collective, *torque)

    def idle(self, state: VehicleState) -> tuple[float, float, float, float]:
        """ESC commands of PX4's idle on the ground (landed, no take-off asked for): the least
        lift, level, integrators at zero (PX4's position and rate controllers reset theirs)."""
        vi, ri = self._vel_int, self._rate_int
        vi[0] = vi[1] = vi[2] = ri[0] = ri[1] = ri[2] = 0.0
        roll_sp, pitch_sp, collective = self._attitude_and_thrust(state, _IDLE_ACCEL)
        return mix(collective, *self._rate_loop(state, self._rates(state, roll_sp, pitch_sp, 0.0)))

    def _velocity_command(self, state: VehicleState, sp: Setpoint) -> tuple[float, float, float]:
        """Position P plus feed-forward per axis, limited to the configured speeds."""
        g = self._g
        (pn, pe, pd), (tn, te, td) = state.position_ned_m, sp.position_ned_m
        fn, fe, fd = sp.velocity_ned_m_s
        fn, fe, fd = _finite(fn, 0.0), _finite(fe, 0.0), _finite(fd, 0.0)
        vn = g.pos_p_xy * (tn - pn) + fn if tn - tn == 0.0 else fn
        ve = g.pos_p_xy * (te - pe) + fe if te - te == 0.0 else fe
        vd = g.pos_p_z * (td - pd) + fd if td - td == 0.0 else fd
        speed = math.hypot(vn, ve)
        if speed > g.max_xy_m_s:
            scale = g.max_xy_m_s / speed
            vn, ve = vn * scale, ve * scale
        if g.vel_cmd_blend < 1.0:
            vn, ve = self._lag_xy(vn, ve, state.velocity_ned_m_s)
        up, down = g.max_up_m_s, g.max_down_m_s
        return vn, ve, (-up if vd < -up else down if vd > down else vd)

    def _lag_xy(self, vn: float, ve: float, velocity: tuple[float, float, float]) -> tuple[float, float]:
        """The horizontal command through a first-order lag (``vel_cmd_tau_s``), which starts
        from the velocity flown: an autopilot that answers a new velocity more slowly."""
        lagged = self._lagged_xy if self._lagged_xy is not None else (velocity[0], velocity[1])
        k = self._g.vel_cmd_blend
        lagged = (lagged[0] + k * (vn - lagged[0]), lagged[1] + k * (ve - lagged[1]))
        self._lagged_xy = lagged
        return lagged

    def _acceleration(
        self, state: VehicleState, vel_cmd: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        """Velocity PI -> desired NED acceleration.

        Horizontal integrators only run near the setpoint (so a step does not wind them up
        into a slow overshoot; the vertical one must always run, it learns the hover thrust,
        but not while the thrust saturates).
        All freeze while touching a surface, where contact forces would wind them up.
        """
        g, vi = self._g, self._vel_int
        vn, ve, vd = state.velocity_ned_m_s
        en, ee, ed = vel_cmd[0] - vn, vel_cmd[1] - ve, vel_cmd[2] - vd
        if not state.on_ground:
            if en * en + ee * ee < g.vel_i_zone2:
                lim = g.vel_i_max_xy
                i0 = vi[0] + g.vel_i_xy_dt * en
                i1 = vi[1] + g.vel_i_xy_dt * ee
                vi[0] = -lim if i0 < -lim else lim if i0 > lim else i0
                vi[1] = -lim if i1 < -lim else lim if i1 > lim else i1
            lim_z = g.vel_i_max_z
            i2 = vi[2] + g.vel_i_z_dt * ed
            i2 = -lim_z if i2 < -lim_z else lim_z if i2 > lim_z else i2
            if _MIN_LIFT < GRAVITY_M_S2 - g.vel_p_z * ed - i2 < _MAX_LIFT:  # no windup
                vi[2] = i2
        return g.vel_p_xy * en + vi[0], g.vel_p_xy * ee + vi[1], g.vel_p_z * ed + vi[2]

    def _attitude_and_thrust(
        self, state: VehicleState, accel: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        """Roll and pitch that point the thrust along ``accel - g``, and the collective."""
        g = self._g
        an, ae, ad = accel
        lift = GRAVITY_M_S2 - ad
        lift = _MIN_LIFT if lift < _MIN_LIFT else _MAX_LIFT if lift > _MAX_LIFT else lift
        horizontal = math.hypot(an, ae)
        max_horizontal = lift * g.tan_tilt
        if horizontal > max_horizontal:
            scale = max_horizontal / horizontal
            an, ae = an * scale, ae * scale
        roll, pitch, yaw = state.attitude_rad
        cy, sy = math.cos(yaw), math.sin(yaw)
        forward, right = cy * an + sy * ae, cy * ae - sy * an
        pitch_sp = math.atan2(-forward, lift)
        roll_sp = math.atan2(right, math.hypot(forward, lift))
        # tilt compensation with the attitude actually flown (as PX4 does)
        tilt_cos = math.cos(roll) * math.cos(pitch)
        self.lift_ratio = lift / (GRAVITY_M_S2 * (tilt_cos if tilt_cos > 0.5 else 0.5))
        self.collective = throttle_for_lift(self.lift_ratio, g.hover_throttle, g.thrust_quadratic)
        return roll_sp, pitch_sp, self.collective

    def _yaw_rate(self, state: VehicleState, sp: Setpoint) -> float:
        g = self._g
        yaw_sp = sp.yaw_rad
        if yaw_sp - yaw_sp == 0.0:
            rate = g.att_p_yaw * _wrap_pi(yaw_sp - state.attitude_rad[2])
        else:
            rate = _finite(sp.yaw_rate_rad_s, 0.0)
        limit = g.max_yaw_rate
        return -limit if rate < -limit else limit if rate > limit else rate

    def _rates(
        self, state: VehicleState, roll_sp: float, pitch_sp: float, yaw_rate_sp: float
    ) -> tuple[float, float, float]:
        """Attitude P on Euler angles, turned into body rates by the Euler kinematics."""
        g = self._g
        roll, pitch, _ = state.attitude_rad
        roll_dot = g.att_p_rp * (roll_sp - roll)
        pitch_dot = g.att_p_rp * (pitch_sp - pitch)
        sr, cr = math.sin(roll), math.cos(roll)
        sp_, cp = math.sin(pitch), math.cos(pitch)
        p = roll_dot - sp_ * yaw_rate_sp
        q = cr * pitch_dot + sr * cp * yaw_rate_sp
        lim = g.max_rate_rp
        return (
            -lim if p < -lim else lim if p > lim else p,
            -lim if q < -lim else lim if q > lim else q,
            -sr * pitch_dot + cr * cp * yaw_rate_sp,
        )

    def _rate_loop(
        self, state: VehicleState, rates_sp: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        """Body-rate PID (derivative on measurement) -> normalised roll, pitch, yaw torques."""
        g, ri = self._g, self._rate_int
        p, q, r = rates = state.rates_frd_rad_s
        pp, pq, _ = self._prev_rates
        self._prev_rates = rates
        ep, eq, er = rates_sp[0] - p, rates_sp[1] - q, rates_sp[2] - r
        if not state.on_ground:
            lim, lim_yaw = g.rate_i_max, g.rate_i_max_yaw
            i0 = ri[0] + g.rate_i_rp_dt * ep
            i1 = ri[1] + g.rate_i_rp_dt * eq
            i2 = ri[2] + g.rate_i_yaw_dt * er
            ri[0] = -lim if i0 < -lim else lim if i0 > lim else i0
            ri[1] = -lim if i1 < -lim else lim if i1 > lim else i1
            ri[2] = -lim_yaw if i2 < -lim_yaw else lim_yaw if i2 > lim_yaw else i2
        kp, kd = g.rate_p_rp, g.rate_d_rp_per_dt
        return (
            kp * ep + ri[0] - kd * (p - pp),
            kp * eq + ri[1] - kd * (q - pq),
            g.rate_p_yaw * er + ri[2],
        )


def wants_takeoff(state: VehicleState, sp: Setpoint) -> bool:
    """PX4's take-off check for a landed vehicle: a position setpoint more than 0.2 m higher or
    a climb faster than 0.3 m/s; anything else keeps it idle on the ground."""
    return sp.position_ned_m[2] < state.position_ned_m[2] - TAKEOFF_HEIGHT_M or sp.velocity_ned_m_s[2] < -TAKEOFF_CLIMB_M_S
