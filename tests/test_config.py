"""Configuration: the shipped presets match the code, and bad input is refused clearly."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import CompanionConfig, load_companion_config
from companion.errors import ConfigError
from sitl.cli import build_config
from sitl.config import SitlConfig, load_sitl_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _toml(tmp_path: Path, text: str, name: str = "c.toml") -> Path:
    """A config file holding ``text`` in the test's folder."""
    path = tmp_path / name
    path.write_text(text)
    return path


def test_default_toml_is_exactly_the_built_in_defaults() -> None:
    assert load_sitl_config(CONFIGS / "default.toml") == SitlConfig()
    assert load_companion_config(CONFIGS / "default.toml") == CompanionConfig()


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.toml")), ids=lambda p: p.name)
def test_every_shipped_preset_loads(path: Path) -> None:
    load_sitl_config(path)
    load_companion_config(path)


def test_unknown_key_names_the_key(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="learner.learning_rat"):
        load_companion_config(_toml(tmp_path, "[companion.learner]\nlearning_rat = 0.1\n"))


def test_wrong_type_and_range_are_explained(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as info:
        load_sitl_config(_toml(tmp_path, '[sitl.clock]\nspeed = -3\nmode = "fast"\n'))
    assert "clock.speed" in str(info.value) and "clock.mode" in str(info.value)


def test_missing_file_bad_toml_and_unknown_table(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_companion_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_sitl_config(_toml(tmp_path, "[sitl\n", "bad.toml"))
    with pytest.raises(ConfigError, match="unknown top-level"):
        load_companion_config(_toml(tmp_path, "[drone]\nx = 1\n", "extra.toml"))


def test_partial_file_keeps_other_defaults(tmp_path: Path) -> None:
    cfg = load_companion_config(_toml(tmp_path, "[companion.session]\nmax_steps = 50\n"))
    assert cfg.session.max_steps == 50
    assert cfg.learner == CompanionConfig().learner


def test_sitl_command_line_overrides_are_validated() -> None:
    cfg = build_config(SitlConfig(), clock="lockstep", speed=4.0, udp=["0:14540"], tcp=-1, no_camera=True)
    assert cfg.clock.mode == "lockstep" and cfg.network.tcp_port is None and not cfg.camera.enabled
    with pytest.raises(ConfigError, match="clock.mode"):
        build_config(SitlConfig(), clock="sometimes")


def test_telemetry_slower_than_twice_the_control_rate_is_refused(tmp_path) -> None:
    """Steps need telemetry newer than the last step's: a slower stream would hold by design."""
    with pytest.raises(ConfigError, match="telemetry_rate_hz = 15 is below 2 x the control rate"):
        load_companion_config(_toml(tmp_path, "[companion.link]\ntelemetry_rate_hz = 15.0\n"))
    allowed = _toml(tmp_path, "[companion.link]\ntelemetry_rate_hz = 0.0\n")  # the vehicle's own rates
    assert load_companion_config(allowed).link.telemetry_rate_hz == 0.0
