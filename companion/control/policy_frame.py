"""The position the policy sees: the vehicle's place from home, moved into the frame the policy
learned in.

A policy observes its own position (``north_m``, ``east_m``, ``down_m``, docs/camera.md). In our
SITL's experiments the pad sits on the ground vehicle's roof, 1.5 m above home; on a real
autopilot's SITL the rendered pad lies on its ground, at home's height. The same place above the
pad then reads 1.5 m lower to the policy than it did in training, while the picture shows the
pad's true size: inputs no demonstration had. ``[companion.session] policy_pad_ned_m`` names where
the pad was in the policy's world; the position is shifted by that minus ``pad_ned_m``, so the
pad sits where the policy learned it. Heights the companion judges (the fence, touchdown, the
start point) stay from home: only the observation moves.
"""

from __future__ import annotations

from collections.abc import Sequence

from companion.msg.snapshot import Vec3


def policy_position(from_home_ned_m: Sequence[float], pad_ned_m: Sequence[float],
                    policy_pad_ned_m: Sequence[float] | None) -> Vec3:
    """``from_home_ned_m`` as the policy sees it: unchanged without ``policy_pad_ned_m``, else
    moved by ``policy_pad_ned_m - pad_ned_m`` (the pad's place there minus its place here)."""
    n, e, d = (float(v) for v in from_home_ned_m)
    if policy_pad_ned_m is None:
        return (n, e, d)
    return (n + float(policy_pad_ned_m[0]) - float(pad_ned_m[0]),
            e + float(policy_pad_ned_m[1]) - float(pad_ned_m[1]),
            d + float(policy_pad_ned_m[2]) - float(pad_ned_m[2]))
