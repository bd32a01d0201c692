"""PX4 custom-mode encoding and mode-switch rules."""

import pytest

from sitl.modes import Mode, refusal


@pytest.mark.parametrize(
    ("mode", "custom"),
    [
        (Mode.POSCTL, 3 << 16),
        (Mode.OFFBOARD, 6 << 16),
        (Mode.AUTO_TAKEOFF, (4 << 16) | (2 << 24)),
        (Mode.AUTO_LOITER, (4 << 16) | (3 << 24)),
        (Mode.AUTO_LAND, (4 << 16) | (6 << 24)),
    ],
)
def test_custom_mode_is_main_shift_16_or_sub_shift_24(mode: Mode, custom: int) -> None:
    assert mode.custom_mode == custom
    assert Mode.from_custom_mode(custom) is mode


def test_px4_names_use_dots() -> None:
    assert Mode.AUTO_LOITER.px4_name == "AUTO.LOITER"
    assert Mode.OFFBOARD.px4_name == "OFFBOARD"


def test_auto_without_sub_mode_is_loiter() -> None:
    assert Mode.from_main_sub(4, 0) is Mode.AUTO_LOITER


def test_unknown_mode_is_an_error() -> None:
    with pytest.raises(ValueError, match="unsupported PX4 mode"):
        Mode.from_main_sub(9, 9)


def test_offboard_needs_a_setpoint_stream() -> None:
    assert refusal(Mode.OFFBOARD, armed=True, landed=False, setpoints_fresh=False) is not None
    assert refusal(Mode.OFFBOARD, armed=True, landed=False, setpoints_fresh=True) is None
    assert refusal(Mode.POSCTL, armed=False, landed=True, setpoints_fresh=False) is None
