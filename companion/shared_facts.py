"""The physical facts the companion and our SITL both hold, checked to agree.

A person (or the scripted expert) knows the pad's size and the camera's view; the session knows
where the pad is and, on a vehicle without a simulator, where episodes start. Our SITL holds the
same facts for the world it simulates. Each is set in its own table of the config file
(configs/default.toml), and when the companion flies our SITL from the same file, a disagreement
is refused before anything starts: a companion told the pad is 0.7 m wide over a 0.5 m pad would
learn, and score, on a world that is not there. The camera's image size is set once, in
``[sitl.camera]``; a camera of another kind reports its own with its first frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from companion.config import CompanionConfig
from companion.errors import ConfigError
from sitl.config import SitlConfig


@dataclass(frozen=True)
class SharedFact:
    """One fact: where the companion keeps it, where the SITL keeps it."""

    companion_key: str
    companion_value: Callable[[CompanionConfig], float]
    sitl_key: str
    sitl_value: Callable[[SitlConfig], float]


FACTS: tuple[SharedFact, ...] = (
    SharedFact("[companion.pilot] pad_radius_m", lambda c: c.pilot.pad_radius_m,
               "[sitl.world] pad_radius_m", lambda s: s.world.pad_radius_m),
    SharedFact("[companion.pilot] camera_hfov_deg", lambda c: c.pilot.camera_hfov_deg,
               "[sitl.camera] hfov_deg", lambda s: s.camera.hfov_deg),
    SharedFact("-[companion.session] pad_ned_m[2] (the pad's height)", lambda c: -c.session.pad_ned_m[2],
               "[sitl.world] vehicle_height_m", lambda s: s.world.vehicle_height_m),
    SharedFact("[companion.session] start_height_above_pad_m", lambda c: c.session.start_height_above_pad_m,
               "[sitl.world] start_height_above_pad_m", lambda s: s.world.start_height_above_pad_m),
    SharedFact("[companion.session] start_xy_range_m", lambda c: c.session.start_xy_range_m,
               "[sitl.world] start_xy_range_m", lambda s: s.world.start_xy_range_m),
)


def disagreements(cfg: CompanionConfig, sitl: SitlConfig) -> list[str]:
    """Each shared fact the two configs set differently, as "key = a but key = b"."""
    return [f"{f.companion_key} = {f.companion_value(cfg):g} but {f.sitl_key} = {f.sitl_value(sitl):g}"
            for f in FACTS if f.companion_value(cfg) != f.sitl_value(sitl)]


def check_shared_facts(cfg: CompanionConfig, sitl: SitlConfig) -> None:
    """ConfigError naming every disagreement, before our SITL starts for this companion."""
    found = disagreements(cfg, sitl)
    if found:
        raise ConfigError("the companion and the SITL it flies disagree about the world: " + "; ".join(found)
                          + ". Set both to the same value in the config file")


def image_size_px(sitl: SitlConfig) -> tuple[int, int]:
    """Our SITL camera's image (width, height): what the observer expects before a first frame."""
    return (sitl.camera.width_px, sitl.camera.height_px)
