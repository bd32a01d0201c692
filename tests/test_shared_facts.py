"""The physical facts the companion and our SITL both hold (companion/shared_facts.py): the
default config agrees with itself, and a file that sets one fact two ways is refused before our
SITL starts, naming both keys."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.app import RunOptions, expected_image_size, vehicle_connection
from companion.config import load_companion_config
from companion.errors import ConfigError
from companion.inprocess import sitl_config_for
from companion.shared_facts import FACTS, disagreements
from sitl.config import load_sitl_config

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("name", ["default.toml", "paper.toml", "precland.toml"])
def test_the_committed_configs_agree(name: str) -> None:
    path = REPO / "configs" / name
    assert disagreements(load_companion_config(path), load_sitl_config(path)) == []


def test_every_fact_is_read_from_both_sides() -> None:
    cfg, sitl = load_companion_config(None), load_sitl_config(None)
    assert len(FACTS) == 5
    assert all(f.companion_value(cfg) == f.sitl_value(sitl) for f in FACTS)


def _file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "world.toml"
    path.write_text(text)
    return path


def test_a_pad_of_two_sizes_is_refused_before_the_sitl_starts(tmp_path: Path) -> None:
    path = _file(tmp_path, "[companion.pilot]\npad_radius_m = 0.7\n\n[sitl.camera]\nhfov_deg = 80.0\n")
    cfg = load_companion_config(path)
    with pytest.raises(ConfigError) as err:
        sitl_config_for(cfg, RunOptions(config_path=path))
    text = str(err.value)
    assert "[companion.pilot] pad_radius_m = 0.7 but [sitl.world] pad_radius_m = 0.5" in text
    assert "[companion.pilot] camera_hfov_deg = 90 but [sitl.camera] hfov_deg = 80" in text
    with pytest.raises(ConfigError, match="disagree about the world"), \
            vehicle_connection(cfg, RunOptions(config_path=path), lockstep=True):
        pass


def test_a_start_box_and_a_pad_height_set_one_way_only_are_refused(tmp_path: Path) -> None:
    path = _file(tmp_path, "[companion.session]\nstart_height_above_pad_m = 3.0\npad_ned_m = [0.0, 0.0, -1.0]\n")
    found = disagreements(load_companion_config(path), load_sitl_config(path))
    assert len(found) == 2 and "start_height_above_pad_m = 3 but" in found[1] and "vehicle_height_m = 1.5" in found[0]


def test_a_real_autopilot_is_not_checked(tmp_path: Path) -> None:
    """With --connect the SITL is not ours: the companion's own facts stand alone."""
    path = _file(tmp_path, "[companion.session]\nstart_height_above_pad_m = 3.0\n")
    opts = RunOptions(config_path=path, connection="udpin:127.0.0.1:14540")
    with vehicle_connection(load_companion_config(path), opts, lockstep=False) as (connection, sitl):
        assert connection == "udpin:127.0.0.1:14540" and sitl is None


def test_the_image_size_is_set_once_in_the_sitl_camera(tmp_path: Path) -> None:
    path = _file(tmp_path, "[sitl.camera]\nwidth_px = 640\nheight_px = 480\n")
    assert expected_image_size(RunOptions(config_path=path)) == (640, 480)
    assert expected_image_size(RunOptions()) == (320, 240)
