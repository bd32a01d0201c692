"""The pad as the detector found it in one image (companion/vision/perception.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class PadDetection:
    """The pad in the image: centre and radius in pixels; ``partial`` if it crosses the border."""

    u_px: float
    v_px: float
    radius_px: float
    partial: bool

    def __post_init__(self) -> None:
        if not all(math.isfinite(x) for x in (self.u_px, self.v_px, self.radius_px)):
            raise ValueError(f"pad detection must be finite, got {self}")
        if self.radius_px <= 0:
            raise ValueError(f"pad radius must be positive, got {self.radius_px}")
