"""Every error the project raises on purpose, in one hierarchy.

Each message says what went wrong *and* what to do about it, so that a person at the field
can act on it without reading the code.
"""

from __future__ import annotations


class ColError(Exception):
    """Base class: anything the project raises deliberately."""


class ConfigError(ColError, ValueError):
    """A configuration file or value is invalid."""


class LinkError(ColError):
    """Base for problems talking MAVLink to the vehicle."""


class LinkLost(LinkError):
    """No telemetry from the vehicle for longer than the link timeout."""


class LinkTimeout(LinkError):
    """The vehicle did not answer in time (no heartbeat, no ACK)."""


class CommandRejected(LinkError):
    """A command was refused: by the vehicle (a COMMAND_ACK other than ACCEPTED, with the
    reasons it gave in STATUSTEXT), or by the companion before asking it (``origin`` says which).
    """

    def __init__(self, command: str, result: str, hint: str = "", *, origin: str = "vehicle",
                 reasons: tuple[str, ...] = ()) -> None:
        self.command = command
        self.result = result
        self.origin = origin
        self.reasons = tuple(reasons)
        if origin == "companion":
            msg = f"the companion refused {command} without asking the vehicle ({result})"
        else:
            msg = f"vehicle rejected {command}: {result}"
            if self.reasons:
                msg += " (vehicle says: " + "; ".join(repr(r) for r in self.reasons) + ")"
        super().__init__(f"{msg}. {hint}" if hint else msg)


class CameraError(ColError):
    """A camera source cannot be opened or has stopped delivering frames."""


class DatasetCorrupt(ColError):
    """A dataset file cannot be read as the documented CSV format."""


class CheckpointError(ColError):
    """A checkpoint file is missing, corrupt or incompatible with this version."""


class SimulatorError(ColError):
    """The SITL's control surface refused a request or cannot be reached."""


class InputDeviceError(ColError):
    """A human input device (gamepad, joystick) cannot be found or read."""


class SessionOnly(ColError):
    """Something only the session's own episode loop flies or records as it would (the batched
    evaluation met it: an episode that could not start); evaluate through the session."""
