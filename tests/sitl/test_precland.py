"""Precision landing as pure logic with injected time: PX4's precland and target estimator,
ArduCopter's AC_PrecLand, and LANDING_TARGET's two forms."""

from __future__ import annotations

import math

import pytest

from sitl.ardupilot_plnd import PLND_DEFAULTS, ApPrecLand, ApState, ApTargetEstimator
from sitl.landing_target import (
    FRAME_BODY_FRD,
    FRAME_LOCAL_NED,
    LandingTargetRejected,
    TargetEstimate,
    TargetMeasurement,
    angles_of,
    body_to_ned,
    ned_to_body,
    ray_from_angles,
    relative_from_ray,
)
from sitl.px4_precland import (
    PX4_LTEST_DEFAULTS,
    PX4_PRECLAND_DEFAULTS,
    PrecLandMode,
    Px4PrecLand,
    Px4State,
    Px4TargetEstimator,
    VehiclePose,
)

DT = 0.05


def px4_params(**changes: float) -> dict[str, float]:
    return {**PX4_PRECLAND_DEFAULTS, **PX4_LTEST_DEFAULTS, **changes}


def ap_params(**changes: float) -> dict[str, float]:
    return {**PLND_DEFAULTS, "PLND_ENABLED": 1, "PLND_TYPE": 1, **changes}


def pose(t: float, n: float = 0.0, e: float = 0.0, d: float = -5.0, v: tuple[float, float, float] = (0.0, 0.0, 0.0),
         height: float | None = None) -> VehiclePose:
    return VehiclePose(t, (n, e, d), v, (0.0, 0.0, 0.0), -d if height is None else height)


def target(t: float, n: float, e: float, d: float = 0.0) -> TargetEstimate:
    return TargetEstimate(t, n, e, d)


# ----- LANDING_TARGET -------------------------------------------------------------------------
def test_nan_fields_are_refused_not_flown() -> None:
    with pytest.raises(LandingTargetRejected, match="angle_x"):
        TargetMeasurement(0.0, math.nan, 0.0, 3.0, FRAME_BODY_FRD, False)
    with pytest.raises(LandingTargetRejected, match="z"):
        TargetMeasurement(0.0, 0.0, 0.0, 3.0, FRAME_LOCAL_NED, True, 1.0, 2.0, math.inf)
    TargetMeasurement(0.0, 0.1, -0.1, 3.0, FRAME_LOCAL_NED, False, math.nan, 0.0, 0.0)  # x unused: fine


def test_angles_and_rays_invert_each_other_and_follow_the_camera_convention() -> None:
    ax, ay = angles_of((1.0, 2.0, 4.0))  # forward 1, right 2, 4 below
    assert ax > 0 and ay < 0  # right: +angle_x; forward: -angle_y (image y points aft)
    x, y, z = ray_from_angles(ax, ay)
    assert (x * 4, y * 4, z * 4) == pytest.approx((1.0, 2.0, 4.0))
    att = (0.1, -0.2, 1.0)
    assert ned_to_body(body_to_ned((1.0, 2.0, 3.0), att), att) == pytest.approx((1.0, 2.0, 3.0))
    rel = relative_from_ray((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), 5.0)
    assert rel == pytest.approx((0.0, 0.0, 5.0))


# ----- PX4 target estimator -------------------------------------------------------------------
def test_px4_takes_local_ned_positions_as_they_are_and_refuses_body_frd() -> None:
    est = Px4TargetEstimator(px4_params().__getitem__)
    est.measure(TargetMeasurement(1.0, 0, 0, 0, FRAME_LOCAL_NED, True, 3.0, -2.0, 1.0), pose(1.0))
    got, updated = est.take()
    assert updated and got == TargetEstimate(1.0, 3.0, -2.0, 1.0)
    assert est.take()[1] is False
    with pytest.raises(LandingTargetRejected, match="coordinate frame 12 unsupported"):
        est.measure(TargetMeasurement(1.0, 0, 0, 5, FRAME_BODY_FRD, True, 1.0, 0.0, 4.0), pose(1.0))


def _track_moving_pad(mode: int, seconds: float = 8.0) -> float:
    """Hover at the origin, 5 m above a pad driving north at 0.25 m/s (from 1 m behind to 1 m
    ahead), angles at 10 Hz: the error of the estimate at the end."""
    est = Px4TargetEstimator(px4_params(LTEST_MODE=mode).__getitem__)
    t = 0.0
    while t < seconds:
        p = pose(t)
        pad_n = -1.0 + 0.25 * t
        est.predict(p)
        if round(t / DT) % 2 == 0:
            ax, ay = angles_of((pad_n, 0.0, 5.0))
            est.measure(TargetMeasurement(t, ax, ay, 0.0, FRAME_BODY_FRD, False), p)
        t += DT
    got, _ = est.take()
    assert got is not None
    return abs(got.north_m - (-1.0 + 0.25 * got.time_s))


def test_px4_estimator_follows_a_moving_pad_in_moving_mode_and_lags_in_stationary_mode() -> None:
    moving, stationary = _track_moving_pad(0), _track_moving_pad(1)
    assert moving < 0.1 and stationary > 0.3


def test_px4_sensor_rotation_turns_the_angles_into_the_body_frame() -> None:
    est = Px4TargetEstimator(px4_params().__getitem__)
    assert est._body_ray(TargetMeasurement(0.0, 0.1, 0.2, 0.0, FRAME_BODY_FRD, False)) == pytest.approx((-0.2, 0.1, 1.0))
    est = Px4TargetEstimator(px4_params(LTEST_SENS_ROT=0).__getitem__)
    assert est._body_ray(TargetMeasurement(0.0, 0.1, 0.2, 0.0, FRAME_BODY_FRD, False)) == pytest.approx((0.1, 0.2, 1.0))


def test_px4_estimator_resets_after_two_seconds_without_measurements() -> None:
    est = Px4TargetEstimator(px4_params().__getitem__)
    est.predict(pose(0.0))
    est.measure(TargetMeasurement(0.0, 0.0, 0.0, 0.0, FRAME_BODY_FRD, False), pose(0.0))
    assert est.active
    est.predict(pose(2.5))
    assert not est.active


# ----- PX4 precland state machine -------------------------------------------------------------
class Px4Run:
    """A precland run: the vehicle jumps to what the guidance asks (a perfect controller)."""

    def __init__(self, mode: PrecLandMode = PrecLandMode.REQUIRED, **params: float) -> None:
        self.p = px4_params(**params)
        self.pl = Px4PrecLand(self.p.__getitem__)
        self.t, self.n, self.e, self.d = 0.0, 0.0, 0.0, -5.0
        self.pl.start(pose(0.0, d=self.d), mode)
        self.states = [self.pl.state]

    def step(self, tgt: TargetEstimate | None, updated: bool, follow: bool = True) -> None:
        self.t += DT
        g = self.pl.update(pose(self.t, self.n, self.e, self.d), tgt, updated)
        if follow:
            step = min(1.0, 5.0 * DT / max(math.hypot(g.north_m - self.n, g.east_m - self.e), 1e-9))
            self.n += (g.north_m - self.n) * step
            self.e += (g.east_m - self.e) * step
            self.d = self.d + 0.7 * DT if g.descending else g.down_m  # type: ignore[assignment]
        if self.pl.state is not self.states[-1]:
            self.states.append(self.pl.state)

    def run(self, seconds: float, tgt_at: tuple[float, float] | None, **kw: bool) -> None:
        end = self.t + seconds
        while self.t < end:
            tgt = None if tgt_at is None else target(self.t, *tgt_at)
            self.step(tgt, tgt is not None, **kw)


def test_px4_approaches_at_altitude_then_descends_only_within_pld_hacc_rad() -> None:
    run = Px4Run()
    run.run(1.0, (4.0, 3.0))
    assert run.pl.state is Px4State.HORIZONTAL_APPROACH and run.d == -5.0  # no descent yet
    run.run(6.0, (4.0, 3.0))
    assert run.states[:3] == [Px4State.START, Px4State.HORIZONTAL_APPROACH, Px4State.DESCEND_ABOVE_TARGET]
    assert (run.n, run.e) == pytest.approx((4.0, 3.0), abs=0.05)
    assert run.d > -5.0  # descending over the target


def test_px4_never_descends_while_the_target_stays_beyond_the_acceptance_radius() -> None:
    """A pad it lags by more than PLD_HACC_RAD: PX4 (main, 2026) has no time limit on the
    approach (the real one spent 29 s there, wandering 0.3 m around a fixed point)."""
    run = Px4Run(PLD_HACC_RAD=0.2)
    run.run(60.0, (4.0, 0.0), follow=False)
    assert run.pl.state is Px4State.HORIZONTAL_APPROACH and run.d == -5.0


def test_px4_searches_by_climbing_when_the_target_is_lost_then_falls_back() -> None:
    run = Px4Run(PLD_SRCH_ALT=8.0, PLD_SRCH_TOUT=4.0, PLD_BTOUT=1.0)
    run.run(3.0, (1.0, 0.0))
    assert run.pl.state is Px4State.DESCEND_ABOVE_TARGET or run.pl.state is Px4State.HORIZONTAL_APPROACH
    run.run(1.5, None)  # lost for longer than PLD_BTOUT: back to start, holding
    assert Px4State.START in run.states[2:]
    run.run(1.5, None)  # 1 s at the start point without the target: search
    assert run.pl.state is Px4State.SEARCH
    lowest = run.d
    for _ in range(60):
        run.run(DT, None)
        lowest = min(lowest, run.d)
    assert lowest == pytest.approx(-8.0)  # climbed to PLD_SRCH_ALT
    run.run(2.0, None)
    assert run.pl.state is Px4State.FALLBACK and "Search timed out" in run.pl.events
    run.run(0.5, None)
    assert (run.n, run.e) == pytest.approx((1.0, 0.0), abs=0.05)  # lands where the target was last seen


def test_px4_search_finds_the_target_again_and_approaches() -> None:
    run = Px4Run(PLD_BTOUT=1.0, PLD_SRCH_TOUT=20.0)
    run.run(3.5, None)
    assert run.pl.state is Px4State.SEARCH
    run.run(2.0, (2.0, 0.0))
    assert run.pl.state is Px4State.HORIZONTAL_APPROACH


def test_px4_falls_back_after_pld_max_srch_losses() -> None:
    run = Px4Run(PLD_MAX_SRCH=1, PLD_BTOUT=0.5, PLD_SRCH_TOUT=0.0)
    for _ in range(2):
        run.run(3.0, (0.5, 0.0))
        run.run(1.0, None)
    assert run.pl.state is Px4State.FALLBACK and run.pl.search_count == 2


def test_px4_opportunistic_without_a_target_lands_normally_at_once() -> None:
    run = Px4Run(PrecLandMode.OPPORTUNISTIC)
    run.run(0.1, None)
    assert run.pl.state is Px4State.FALLBACK


def test_px4_final_approach_keeps_landing_when_the_target_is_lost_near_the_ground() -> None:
    run = Px4Run(PLD_FAPPR_ALT=1.0)
    run.run(5.0, (0.0, 0.0))
    assert run.pl.state is Px4State.DESCEND_ABOVE_TARGET
    while run.d < -0.5:
        run.run(DT, (0.0, 0.0))
    run.run(1.0, None)
    assert run.pl.state is Px4State.FINAL_APPROACH


# ----- ArduPilot ------------------------------------------------------------------------------
def _ap_estimator(**params: float) -> ApTargetEstimator:
    return ApTargetEstimator(ap_params(**params).__getitem__)


def test_ardupilot_takes_body_frd_and_angles_but_not_local_ned() -> None:
    est = _ap_estimator(PLND_EST_TYPE=0)
    est.update(pose(0.0))
    est.measure(TargetMeasurement(0.05, 0, 0, 5.0, FRAME_BODY_FRD, True, 3.0, 0.0, 4.0), None)
    est.update(pose(0.05))
    got = est.estimate(pose(0.05))
    assert got is not None and (got.north_m, got.east_m) == pytest.approx((3.0, 0.0))
    for _ in range(3):  # dropped, said once
        assert not est.measure(TargetMeasurement(0.1, 0, 0, 5.0, FRAME_LOCAL_NED, True, 3.0, 0.0, 4.0), None)
    assert est.events.count("Plnd: Frame not supported") == 1
    assert not est.measure(TargetMeasurement(0.1, 0.0, 0.0, 0.0, FRAME_BODY_FRD, False), None)  # no distance, no rangefinder
    assert est.measure(TargetMeasurement(0.1, 0.0, 0.0, 0.0, FRAME_BODY_FRD, False), 4.0)  # a rangefinder's height


def test_ardupilot_kalman_filter_needs_two_seconds_of_measurements_before_acquiring() -> None:
    est = _ap_estimator()
    t = 0.0
    while t < 1.9:
        est.update(pose(t))
        est.measure(TargetMeasurement(t, 0.0, 0.0, 5.0, FRAME_BODY_FRD, True, 1.0, 0.0, 5.0), None)
        t += 0.1
    assert not est.acquired
    for _ in range(3):
        est.update(pose(t))
        est.measure(TargetMeasurement(t, 0.0, 0.0, 5.0, FRAME_BODY_FRD, True, 1.0, 0.0, 5.0), None)
        t += 0.1
    assert est.acquired and "PrecLand: Init Complete" in est.events
    est.update(pose(t))
    est.update(pose(t + 2.5))
    assert not est.acquired and "PrecLand: Target Lost" in est.events


def test_ardupilot_land_repositions_over_the_target_and_holds_height_while_far() -> None:
    pl = ApPrecLand(ap_params().__getitem__, rangefinder=False)
    pl.start(pose(0.0))
    far = pl.update(pose(0.1), target(0.1, 4.0, 0.0, 0.0), 0.5)
    assert (far.north_m, far.east_m, far.down_m) == (4.0, 0.0, -5.0)  # beyond PLND_XY_DIST_MAX: no descent
    near = pl.update(pose(0.2, n=2.0), target(0.2, 4.0, 0.0, 0.0), 0.5)
    assert near.descending and (near.north_m, near.east_m) == (4.0, 0.0) and pl.state is ApState.PRECISION


def test_ardupilot_moving_target_option_feeds_the_target_velocity_forward() -> None:
    est = _ap_estimator(PLND_OPTIONS=1)
    t = 0.0
    while t < 5.0:
        pad_n = 1.0 * t
        est.update(pose(t))
        if round(t / DT) % 2 == 0:
            est.measure(TargetMeasurement(t, 0.0, 0.0, math.hypot(pad_n, 5.0), FRAME_BODY_FRD, True, pad_n, 0.0, 5.0), None)
        t += DT
    got = est.estimate(pose(t))
    assert got is not None and got.vn_m_s == pytest.approx(1.0, abs=0.2)
    assert _ap_estimator().estimate(pose(0.0)) is None


def _lost_run(strict: int, rangefinder: bool, retries: int = 1) -> ApPrecLand:
    params = ap_params(PLND_STRICT=strict, PLND_RET_MAX=retries, PLND_TIMEOUT=1.0)
    pl = ApPrecLand(params.__getitem__, rangefinder=rangefinder)
    pl.start(pose(0.0))
    pl.update(pose(0.1, d=-4.0), target(0.1, 0.5, 0.0, 0.0), 0.5)
    return pl


def test_ardupilot_lost_target_retries_from_where_it_was_seen_then_obeys_plnd_strict() -> None:
    pl = _lost_run(strict=1, rangefinder=True)
    assert pl.update(pose(0.2, d=-3.0), None, 0.5).descending and pl.state is ApState.DESCEND_LOST
    g = pl.update(pose(1.5, d=-2.5), None, 0.5)  # PLND_TIMEOUT later: back to where it was seen
    assert pl.state is ApState.RETRY and (g.north_m, g.down_m) == (0.0, -4.0)
    pl.update(pose(2.0, d=-4.0), None, 0.5)  # got there, nothing: descend and look again
    pl.update(pose(3.5, d=-3.0), None, 0.5)  # out of retries: land vertically
    assert pl.state is ApState.VERTICAL
    hover = _lost_run(strict=2, rangefinder=True, retries=0)
    hover.update(pose(0.2), None, 0.5)
    assert hover.update(pose(1.5), None, 0.5).down_m == -5.0 and hover.state is ApState.HOVER


def test_ardupilot_without_a_rangefinder_or_strict_0_lands_vertically_when_the_target_is_lost() -> None:
    for pl in (_lost_run(strict=1, rangefinder=False), _lost_run(strict=0, rangefinder=True)):
        g = pl.update(pose(0.2, n=0.3, d=-3.0), None, 0.5)
        assert pl.state is ApState.VERTICAL and g.descending and g.north_m == 0.3


def test_ardupilot_plnd_type_takes_effect_at_the_next_reboot() -> None:
    """Measured on real ArduCopter: PLND_TYPE set at run time reads back 1, yet LAND lands
    vertically; after MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN it lands on the target."""
    from pymavlink.dialects.v20 import common as M

    from sitl.config import PersonalityConfig, SitlConfig
    from sitl.personality import make_vehicle

    v = make_vehicle(SitlConfig(personality=PersonalityConfig(autopilot="ardupilot", prearm_settle_s=0.0)))
    target_msg = TargetMeasurement(0.0, 0, 0, 5.0, FRAME_BODY_FRD, True, 1.0, 0.0, 4.9)
    assert v.set_param("PLND_ENABLED", 1.0) and v.set_param("PLND_TYPE", 1.0)
    for _ in range(5):
        v.step()
    assert not v.landing_target(target_msg)  # no backend: ArduCopter made it at boot
    assert v.reboot(1.0)[0] == M.MAV_RESULT_ACCEPTED and v.params.get("PLND_TYPE") == 1.0
    assert v.rebooting()  # silent: the server sends and reads nothing until it has booted
    while v.rebooting():
        v.step()
    assert v.landing_target(target_msg)
    v.arm(force=True)
    assert v.reboot(1.0)[0] == M.MAV_RESULT_FAILED  # not while armed


def test_px4_precision_land_command_and_mode_as_px4_reports_them() -> None:
    """Command 23 (PX4's NAV_PRECLAND) and DO_SET_MODE (4, 9) enter AUTO.PRECLAND; the HEARTBEAT
    says custom mode 4 << 16 | 9 << 24; refused landed and disarmed; NAV_LAND stays a normal one."""
    from pymavlink.dialects.v20 import common as M

    from sitl.config import SitlConfig
    from sitl.modes import Mode
    from sitl.vehicle import SimVehicle

    v = SimVehicle(SitlConfig())
    assert v.precision_land()[0] == M.MAV_RESULT_DENIED
    v.reset_episode(1)  # hovering, armed
    assert v.precision_land()[0] == M.MAV_RESULT_ACCEPTED and v.mode is Mode.AUTO_PRECLAND
    assert v.heartbeat_mode() == (M.MAV_AUTOPILOT_PX4, (4 << 16) | (9 << 24))
    assert v.precision_landing_state() == "start"
    assert v.land()[0] == M.MAV_RESULT_ACCEPTED and v.mode is Mode.AUTO_LAND
    assert v.set_mode_numbers(4, 9)[0] == M.MAV_RESULT_ACCEPTED and v.mode is Mode.AUTO_PRECLAND
