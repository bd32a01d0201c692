"""A real autopilot's SITL disturbed as ours: [sitl.disturbance] mapped to ArduCopter's SIM_WIND_*
and PX4 SIH's SIH_MASS / SIH_KDV, set with every echo checked and put back at the end."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from companion.app import autopilot_sim_for
from companion.config import load_companion_config
from companion.errors import CommandRejected, ConfigError
from companion.link.sim_params import (
    ARDUPILOT,
    PX4,
    AutopilotSim,
    SimEpisode,
    ardupilot_weather,
    milspec_sigma_u,
    wind_from_deg,
)
from sitl.config import load_sitl_config
from sitl.disturbance import EpisodeDisturbance


class ParamVehicle:
    """The parameters of an autopilot's SITL, as PARAM_REQUEST_READ / PARAM_SET see them."""

    def __init__(self, params: dict[str, float], echo_offset: float = 0.0) -> None:
        self.params = dict(params)
        self.echo_offset = echo_offset
        self.sets: list[tuple[str, float]] = []

    def read_param(self, name: str, timeout_s: float | None = None) -> float | None:
        return self.params.get(name)

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float | None:
        if name not in self.params:
            return None  # an unknown parameter: no PARAM_VALUE comes back
        self.sets.append((name, value))
        self.params[name] = value + self.echo_offset
        return self.params[name]


ARDUCOPTER_PARAMS = {"SIM_WIND_T": 0.0, "SIM_WIND_SPD": 0.0, "SIM_WIND_DIR": 180.0, "SIM_WIND_TURB": 0.0}
SIH_PARAMS = {"SIH_MASS": 1.0, "SIH_KDV": 1.0}


def test_wind_direction_is_where_it_comes_from_in_degrees_true() -> None:
    assert wind_from_deg((1.0, 0.0)) == pytest.approx(180.0)  # blowing north: from the south
    assert wind_from_deg((0.0, 1.0)) == pytest.approx(270.0)  # blowing east: from the west
    assert wind_from_deg((-2.0, 0.0)) == pytest.approx(0.0)
    assert wind_from_deg((0.0, -3.0)) == pytest.approx(90.0)


def test_turbulence_is_milspec_horizontal_intensity_at_the_start_height() -> None:
    h_ft = 9.5 / 0.3048
    assert milspec_sigma_u(2.0, 9.5) == pytest.approx(0.2 / (0.177 + 0.000823 * h_ft) ** 0.4)
    assert milspec_sigma_u(2.0, 9.5) > 0.1 * 2.0  # horizontal exceeds vertical (0.1 W20) near the ground
    assert milspec_sigma_u(2.0, 0.5) == milspec_sigma_u(2.0, 10 * 0.3048)  # the formula's floor, 10 ft
    assert milspec_sigma_u(0.0, 9.5) == 0.0


def test_ardupilot_gets_the_same_wind_at_every_height() -> None:
    params = {p.name: p.value for p in ardupilot_weather(SimEpisode((0.0, -2.0), 1.0), 9.5)}
    assert params["SIM_WIND_T"] == 1  # not ArduPilot's default, which weakens it below 60 m
    assert params["SIM_WIND_SPD"] == pytest.approx(2.0)
    assert params["SIM_WIND_DIR"] == pytest.approx(90.0)
    assert params["SIM_WIND_TURB"] == pytest.approx(milspec_sigma_u(1.0, 9.5), abs=1e-4)


def test_a_seed_gives_the_air_our_sitl_would_fly_it_in(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text("[companion.session]\nautopilot_sim_disturbance = true\n\n[sitl.disturbance]\nlevel = 0.2\n")
    sim = autopilot_sim_for(load_companion_config(path), path)
    assert sim is not None
    ours = EpisodeDisturbance.draw(load_sitl_config(path).disturbance, 7)
    assert sim.episode_for(7) == SimEpisode(ours.wind_ne_m_s, ours.turbulence_w20_m_s, ours.vehicle_velocity_ne_m_s)
    assert sim.pad_drift_for(7) == ours.vehicle_velocity_ne_m_s != (0.0, 0.0)
    assert math.hypot(*sim.episode_for(7).wind_ne_m_s) == pytest.approx(0.2 * 10.0)
    assert sim.episode_for(7) != sim.episode_for(8)  # the direction is drawn per episode
    assert sim.height_m == pytest.approx(8.0 + 1.5)  # the start, above the ground the vehicle left


def test_nothing_asked_builds_nothing(tmp_path: Path) -> None:
    assert autopilot_sim_for(load_companion_config(None), None) is None


def test_arducopter_episode_sets_its_wind_and_the_run_puts_it_back() -> None:
    vehicle = ParamVehicle(ARDUCOPTER_PARAMS)
    sim = AutopilotSim(lambda seed: SimEpisode((float(seed), 0.0), 2.0), height_m=9.5)
    notes = sim.prepare_episode(vehicle, ARDUPILOT, 3)  # type: ignore[arg-type]
    assert vehicle.params["SIM_WIND_SPD"] == 3.0 and vehicle.params["SIM_WIND_DIR"] == 180.0
    assert vehicle.params["SIM_WIND_T"] == 1.0 and vehicle.params["SIM_WIND_TURB"] > 0
    assert notes and notes[0].startswith("sim: SIM_WIND_T=1, SIM_WIND_SPD=3")
    sim.prepare_episode(vehicle, ARDUPILOT, 4)  # type: ignore[arg-type]
    assert vehicle.params["SIM_WIND_SPD"] == 4.0
    sim.restore(vehicle)  # type: ignore[arg-type]
    assert vehicle.params == ARDUCOPTER_PARAMS  # what it had before the first episode, not the last one's


def test_px4_sih_gets_a_heavier_vehicle_once_and_says_it_has_no_wind() -> None:
    vehicle = ParamVehicle(SIH_PARAMS)
    sim = AutopilotSim(lambda seed: SimEpisode((1.0, 0.0), 0.5), height_m=9.5, mass_scale=1.5, drag_scale=2.0)
    for seed in (0, 1):  # scaled from what it had, never compounded episode after episode
        notes = sim.prepare_episode(vehicle, PX4, seed)  # type: ignore[arg-type]
        assert vehicle.params == {"SIH_MASS": 1.5, "SIH_KDV": 2.0}
    assert notes[0] == "sim: SIH_MASS=1.5, SIH_KDV=2"
    assert "PX4 SIH has no wind" in notes[1]
    sim.restore(vehicle)  # type: ignore[arg-type]
    assert vehicle.params == SIH_PARAMS


def test_a_value_the_vehicle_does_not_echo_is_an_error_not_a_silent_calm() -> None:
    def sim() -> AutopilotSim:
        return AutopilotSim(lambda seed: SimEpisode((2.0, 0.0), 0.0), height_m=9.5)

    with pytest.raises(CommandRejected, match="SIM_WIND_T=1: NOT_CONFIRMED"):
        sim().prepare_episode(ParamVehicle(ARDUCOPTER_PARAMS, echo_offset=0.5), ARDUPILOT, 0)  # type: ignore[arg-type]
    with pytest.raises(CommandRejected, match="NO_ANSWER"):  # not its SITL: it has no SIM_WIND_*
        sim().prepare_episode(ParamVehicle({}), ARDUPILOT, 0)  # type: ignore[arg-type]


def test_settings_that_cannot_apply_are_refused_clearly() -> None:
    with pytest.raises(ConfigError, match="PX4 SIH"):
        AutopilotSim(lambda seed: SimEpisode(), 9.5, mass_scale=2.0).params_for(ARDUPILOT, 0)
    with pytest.raises(ConfigError, match="turn it off for a real vehicle"):
        AutopilotSim(lambda seed: SimEpisode(), 9.5).params_for("SOMETHING_ELSE", 0)
    with pytest.raises(ConfigError, match="positive"):
        AutopilotSim(lambda seed: SimEpisode(), 9.5, drag_scale=0.0)
