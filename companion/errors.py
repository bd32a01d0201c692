"""The companion's errors: the project's one hierarchy, defined in :mod:`colcommon.errors`.

The SITL raises the same types without importing the companion; code and users of the
companion keep importing them from here.
"""

from colcommon.errors import (
    CameraError,
    CheckpointError,
    ColError,
    CommandRejected,
    ConfigError,
    DatasetCorrupt,
    InputDeviceError,
    LinkError,
    LinkLost,
    LinkTimeout,
    SessionOnly,
    SimulatorError,
)

__all__ = [
    "ColError",
    "ConfigError",
    "LinkError",
    "LinkLost",
    "LinkTimeout",
    "CommandRejected",
    "CameraError",
    "DatasetCorrupt",
    "CheckpointError",
    "SimulatorError",
    "InputDeviceError",
    "SessionOnly",
]
