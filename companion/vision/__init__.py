"""What the vehicle sees: camera sources, the pad detector, and the 15-value observation built
from telemetry and the detected pad (docs/camera.md)."""
