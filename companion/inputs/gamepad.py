"""A local gamepad through pygame's joystick module (SDL), the trigger being the override.

SDL needs a video subsystem to pump joystick events; the dummy video driver provides one
without a window, so this works headless. Axis numbers and signs come from ``[companion.pilot]``
(``gamepad_axes``, ``gamepad_invert``), in roll, pitch, yaw, throttle order; the defaults suit
an Xbox-style pad in "mode 2" (left stick throttle/yaw, right stick pitch/roll, right trigger
= override). Reading the device is one seam, :class:`JoystickDevice`, that tests replace.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Protocol

from companion.commands import sanitize
from companion.config import PilotConfig
from companion.errors import InputDeviceError
from companion.inputs.base import HumanCommand, HumanInput

if TYPE_CHECKING:
    from companion.msg.observation import Observation


class JoystickDevice(Protocol):
    """The part of ``pygame.joystick.Joystick`` this module uses."""

    def get_numaxes(self) -> int: ...
    def get_numbuttons(self) -> int: ...
    def get_axis(self, index: int) -> float: ...
    def get_button(self, index: int) -> int | bool: ...


def check_layout(device: JoystickDevice, cfg: PilotConfig) -> None:
    """Refuse a mapping that names axes or buttons the device does not have."""
    axes = list(cfg.gamepad_axes) + (
        [cfg.gamepad_trigger_axis] if cfg.gamepad_trigger_axis >= 0 else []
    )
    n_axes, n_buttons = device.get_numaxes(), device.get_numbuttons()
    if any(a >= n_axes for a in axes):
        raise InputDeviceError(
            f"the gamepad has {n_axes} axes but [companion.pilot] uses axes {axes}; "
            "set gamepad_axes / gamepad_trigger_axis to match your device"
        )
    if cfg.gamepad_trigger_button >= n_buttons:
        raise InputDeviceError(
            f"the gamepad has {n_buttons} buttons but gamepad_trigger_button is "
            f"{cfg.gamepad_trigger_button}; pick an existing button or -1"
        )
    if cfg.gamepad_trigger_axis < 0 and cfg.gamepad_trigger_button < 0:
        raise InputDeviceError(
            "no override trigger configured: set gamepad_trigger_axis or gamepad_trigger_button"
        )


def read_device(device: JoystickDevice, cfg: PilotConfig) -> HumanCommand:
    """Sticks and trigger of a device, as a HumanCommand (odd values repaired, not trusted)."""
    values = [
        (-1.0 if inverted else 1.0) * float(device.get_axis(axis))
        for axis, inverted in zip(cfg.gamepad_axes, cfg.gamepad_invert, strict=True)
    ]
    cmd, _ = sanitize(values)
    held = False
    if cfg.gamepad_trigger_axis >= 0:
        held = float(device.get_axis(cfg.gamepad_trigger_axis)) > cfg.gamepad_trigger_threshold
    if cfg.gamepad_trigger_button >= 0:
        held = held or bool(device.get_button(cfg.gamepad_trigger_button))
    return HumanCommand(cmd, override_held=held)


def open_pygame_joystick(index: int) -> JoystickDevice:
    """Open joystick ``index`` with SDL's dummy video driver; a clear error when there is none."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    import pygame  # deferred: only a gamepad session pays for SDL

    pygame.display.init()
    pygame.joystick.init()
    count = pygame.joystick.get_count()
    if index >= count:
        raise InputDeviceError(
            f"no gamepad number {index}: SDL sees {count} joystick(s). Plug in a gamepad "
            "(check it appears in /dev/input), set [companion.pilot] gamepad_index, or choose "
            "another input source such as a ground station's joystick (MANUAL_CONTROL)"
        )
    joystick = pygame.joystick.Joystick(index)
    joystick.init()
    return joystick


class GamepadInput(HumanInput):
    """A local gamepad; ``device`` may be given (tests, other libraries), else pygame opens one."""

    def __init__(self, cfg: PilotConfig, device: JoystickDevice | None = None) -> None:
        self.cfg = cfg
        self._uses_pygame = device is None
        self.device = device if device is not None else open_pygame_joystick(cfg.gamepad_index)
        check_layout(self.device, cfg)

    def read(self, obs: Observation | None = None) -> HumanCommand:
        if not self._uses_pygame:
            return read_device(self.device, self.cfg)
        import pygame

        try:
            pygame.event.pump()  # SDL updates joystick state while pumping events
            return read_device(self.device, self.cfg)
        except pygame.error as exc:
            raise InputDeviceError(
                f"the gamepad stopped answering ({exc}); reconnect it and restart the session"
            ) from exc

    def close(self) -> None:
        if self._uses_pygame:
            import pygame

            pygame.joystick.quit()
