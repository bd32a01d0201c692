"""A touchdown by an autopilot's SITL's truth: the vehicle's first ground contact.

Why: on a real autopilot's SITL the rendered camera draws the pad (companion/vision/rendered.py),
but the pad is no surface there. When it drives, the vehicle touches the autopilot's still
ground while the pad it follows moves on: its controller keeps asking to move, and its land
detector never completes (real ArduCopter with PLND's moving-target option stayed LANDING, armed,
until the episode's time ran out; results/moving-pad/sweep/RUN.md). On a real ground vehicle the
roof would carry it. So where the SITL sends its truth (companion/link/truth.py), the first
truth sample within ``contact_m`` of the ground is the touchdown, scored against the rendered
pad where it is at that moment (companion/control/outcome.py).

The ground is where the truth puts the vehicle standing disarmed before a take-off: ArduCopter
SITL's truth is the local origin's altitude there to 0.1 mm, PX4 SIH's 0.35 m off it in one boot
and not the same at the next (its origin's altitude is a noisy GPS fix;
results/moving-pad/truth-ground/), so the level is
measured, not assumed. Only a SITL has truth, so the session may force the disarm that ends such an
episode (companion/control/session.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.msg.snapshot import VehicleSnapshot

TRUTH_FRESH_MS = 200  # a truth older than this (vehicle time) says nothing about this frame


@dataclass
class TruthGround:
    """Where a SITL's truth puts the ground, and whether the vehicle touches it (module docstring)."""

    contact_m: float = 0.05
    ground_down_m: float | None = None
    """The truth's ``down_m`` of the vehicle standing disarmed on the ground; None: not seen yet."""

    def observe_standing(self, snap: VehicleSnapshot) -> None:
        """A snapshot of the vehicle disarmed on the ground: the level its truth says it stands at."""
        truth = _fresh_truth(snap)
        if truth is not None and not snap.armed and not snap.in_air:
            self.ground_down_m = truth

    def touching(self, snap: VehicleSnapshot) -> bool:
        """The truth of this frame puts the vehicle within ``contact_m`` of the ground."""
        truth = _fresh_truth(snap)
        return self.ground_down_m is not None and truth is not None and truth >= self.ground_down_m - self.contact_m

    def height_m(self, snap: VehicleSnapshot) -> float | None:
        """The truth's height above the ground (None: no level or no fresh truth), for the log."""
        truth = _fresh_truth(snap)
        return None if self.ground_down_m is None or truth is None else self.ground_down_m - truth


def _fresh_truth(snap: VehicleSnapshot) -> float | None:
    pose = snap.true_pose
    if pose is None or abs(snap.time_boot_ms - pose.time_boot_ms) > TRUTH_FRESH_MS:
        return None
    return pose.down_m
