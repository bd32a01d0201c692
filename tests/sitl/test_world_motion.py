"""The ground vehicle's motion: straight on at constant velocity by default (the committed
experiments' arithmetic), and, when asked, a curve and speed changes as a driving vehicle makes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.config import WorldConfig
from sitl.world import World


def world(**motion: float) -> World:
    w = World(WorldConfig(vehicle_velocity_ne_m_s=(1.0, 0.0), **motion))
    w.restart(10.0)
    return w


def test_by_default_the_vehicle_drives_straight_on_as_before() -> None:
    w = world()
    for t in (10.0, 12.5, 47.3):
        assert w.position_ne(t).tolist() == (w.origin_ne + w.velocity_ne * (t - 10.0)).tolist()  # bit for bit
        assert w.velocity_at(t).tolist() == [1.0, 0.0]


def test_a_turning_vehicle_drives_a_circle_of_radius_speed_over_rate() -> None:
    w = world(vehicle_turn_rate_rad_s=0.1)  # 1 m/s: a circle of radius 10 m, clockwise from above
    half = 10.0 + math.pi / 0.1
    assert w.position_ne(half) == pytest.approx([0.0, 20.0], abs=1e-9)  # the diameter away, to the east
    assert w.velocity_at(half) == pytest.approx([-1.0, 0.0], abs=1e-9)  # heading south now
    assert w.velocity_at(10.0 + math.pi / 0.2) == pytest.approx([0.0, 1.0], abs=1e-9)  # a quarter: east
    for t in np.linspace(10.0, 80.0, 15):
        assert np.hypot(*w.velocity_at(t)) == pytest.approx(1.0)  # the speed stays
        assert np.hypot(*(w.position_ne(t) - [0.0, 10.0])) == pytest.approx(10.0)  # on the circle


def test_speed_swings_by_its_share_and_the_position_follows_the_velocity() -> None:
    w = world(vehicle_speed_change=0.5, vehicle_speed_change_period_s=20.0, vehicle_turn_rate_rad_s=-0.05)
    assert np.hypot(*w.velocity_at(15.0)) == pytest.approx(1.5)  # a quarter period: the fastest
    assert np.hypot(*w.velocity_at(25.0)) == pytest.approx(0.5)  # three quarters: the slowest
    for t in np.linspace(10.5, 70.0, 12):  # the closed form is the integral of the velocity
        h = 1e-4
        slope = (w.position_ne(t + h) - w.position_ne(t - h)) / (2 * h)
        assert slope == pytest.approx(w.velocity_at(t), abs=1e-6)
    assert w.position_ne(10.0) == pytest.approx([0.0, 0.0])


def test_a_new_set_velocity_keeps_the_curving_vehicle_where_it_is() -> None:
    w = world(vehicle_turn_rate_rad_s=0.2, vehicle_speed_change=0.3)
    before = w.position_ne(17.0)
    w.set_velocity((0.0, 2.0), 17.0)
    assert w.position_ne(17.0) == pytest.approx(before)
    assert w.velocity_at(17.0) == pytest.approx([0.0, 2.0])  # its curve starts again from here


@pytest.mark.parametrize("bad", [{"vehicle_turn_rate_rad_s": 1.5}, {"vehicle_speed_change": -0.1},
                                 {"vehicle_speed_change": 1.2}, {"vehicle_speed_change_period_s": 0.0}])
def test_a_bad_motion_is_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        WorldConfig(**bad)
