"""The one check every numeric message field passes: a real number (not a bool), finite."""

from __future__ import annotations

import math
import numbers


def finite_real(owner: str, name: str, value: object, hint: str) -> float:
    """``value`` as a float, or a TypeError / ValueError naming ``owner.name`` and saying ``hint``
    (what the caller should do instead). A plain float or int, the every-step case, skips the
    abstract-class check (the slow part of this check: it runs several times a control step)."""
    if isinstance(value, float) or (isinstance(value, int) and not isinstance(value, bool)):
        if not math.isfinite(value):
            raise ValueError(f"{owner}.{name} is {value}; {hint}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{owner}.{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{owner}.{name} is {value}; {hint}")
    return float(value)
