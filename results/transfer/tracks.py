"""Where a policy's episodes go, from a run folder's telemetry (session.tlog), on any vehicle:

    python results/transfer/tracks.py RUN_DIR [RUN_DIR ...]

One JSON line per episode, then one per run folder (``"run": ...``). An episode is a stretch of
the companion's body-frame velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, BODY_NED) with no
gap over 2 s of the vehicle's time (a real autopilot's episodes are apart by the flight to the
next start; our SITL's resets leave no such gap, so on it only the response below means anything). Positions are the vehicle's estimate (LOCAL_POSITION_NED),
the pad at north = east = 0, heights above where the episode ended (its touchdown): on PX4 SIH the
estimate is some 0.2-0.6 m off the truth (docs/camera.md), so these are its picture, not the truth.

Per episode: the start height, the closest pass over the pad (distance and height), the distance
when the vehicle first came down through 4, 2, 1 and 0.5 m, and at the end. Per run: how the
vehicle followed the setpoints in flight (more than 1 m up): for each lag, the least-squares gain
of the measured velocity (estimate, NED) on the commanded one, and the rms difference, horizontal
and vertical; the lag with the smallest rms is the response's delay.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
from pymavlink import mavutil

BODY_NED = 8
EPISODE_GAP_S = 2.0
HEIGHTS_M = (4.0, 2.0, 1.0, 0.5)
LAGS_S = tuple(round(0.1 * i, 1) for i in range(16))


def read(tlog: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Setpoints (t, vx, vy, vz body), estimates (t, n, e, d, vn, ve, vd), yaw (t, yaw)."""
    log = mavutil.mavlink_connection(str(tlog))
    sp, est, att = [], [], []
    while (m := log.recv_match(type=["SET_POSITION_TARGET_LOCAL_NED", "LOCAL_POSITION_NED", "ATTITUDE"],
                               blocking=False)) is not None:
        kind = m.get_type()
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            if m.coordinate_frame == BODY_NED:
                sp.append((m.time_boot_ms / 1e3, m.vx, m.vy, m.vz))
        elif kind == "LOCAL_POSITION_NED":
            est.append((m.time_boot_ms / 1e3, m.x, m.y, m.z, m.vx, m.vy, m.vz))
        else:
            att.append((m.time_boot_ms / 1e3, m.yaw))
    if not sp or not est or not att:
        raise SystemExit(f"{tlog}: no body-frame setpoints, positions or attitude in it")
    return np.array(sp), np.array(est), np.array(att)


def episodes(sp: np.ndarray) -> list[tuple[float, float]]:
    t = sp[:, 0]
    cuts = np.where(np.diff(t) > EPISODE_GAP_S)[0]
    return list(zip(np.r_[t[0], t[cuts + 1]], np.r_[t[cuts], t[-1]], strict=True))


def episode_track(est: np.ndarray, start: float, end: float) -> dict | None:
    seg = est[(est[:, 0] >= start) & (est[:, 0] <= end)]
    if len(seg) < 10:
        return None
    height = -(seg[:, 3] - seg[-1, 3])
    dist = np.hypot(seg[:, 1], seg[:, 2])
    k = int(np.argmin(dist))

    def first_below(h: float) -> float | None:
        idx = np.where(height <= h)[0]
        return round(float(dist[idx[0]]), 2) if len(idx) else None

    return {"start_s": round(start, 1), "duration_s": round(end - start, 1), "start_height_m": round(float(height[0]), 2),
            "closest_m": round(float(dist[k]), 2), "closest_at_height_m": round(float(height[k]), 2),
            "distance_at_height_m": {f"{h:g}": first_below(h) for h in HEIGHTS_M},
            "end_distance_m": round(float(dist[-1]), 2)}


def response(sp: np.ndarray, est: np.ndarray, att: np.ndarray) -> dict:
    """Gain and rms of the measured velocity against the commanded one at each lag, in flight."""
    down_at = np.interp(sp[:, 0], est[:, 0], est[:, 3])
    ground = float(np.max(est[:, 3]))
    fly = sp[ground - down_at > 1.0]
    yaw = np.interp(fly[:, 0], att[:, 0], np.unwrap(att[:, 1]))
    cn = fly[:, 1] * np.cos(yaw) - fly[:, 2] * np.sin(yaw)
    ce = fly[:, 1] * np.sin(yaw) + fly[:, 2] * np.cos(yaw)
    cd = fly[:, 3]
    rows = []
    for lag in LAGS_S:
        t = fly[:, 0] + lag
        vn, ve, vd = (np.interp(t, est[:, 0], est[:, i]) for i in (4, 5, 6))
        c, v = np.r_[cn, ce], np.r_[vn, ve]
        rows.append({"lag_s": lag, "horizontal_gain": round(float(c @ v / (c @ c)), 3),
                     "horizontal_rms_m_s": round(float(np.sqrt(np.mean((v - c) ** 2))), 3),
                     "vertical_gain": round(float(cd @ vd / (cd @ cd)), 3),
                     "vertical_rms_m_s": round(float(np.sqrt(np.mean((vd - cd) ** 2))), 3)})
    best_h = min(rows, key=lambda r: r["horizontal_rms_m_s"])
    best_v = min(rows, key=lambda r: r["vertical_rms_m_s"])
    return {"setpoints_in_flight": len(fly),
            "commanded_horizontal_m_s_p50_p95": [round(float(x), 2) for x in np.percentile(np.hypot(cn, ce), [50, 95])],
            "horizontal_best": best_h, "vertical_best": best_v, "by_lag": rows}


def main() -> None:
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    for run in map(Path, sys.argv[1:]):
        sp, est, att = read(run / "session.tlog")
        tracks = [t for a, b in episodes(sp) if (t := episode_track(est, a, b)) is not None]
        for i, t in enumerate(tracks):
            print(json.dumps({"run": run.name, "episode": i, **t}))
        passed = [t for t in tracks if t["closest_m"] <= 0.5]
        print(json.dumps({"run": run.name, "episodes": len(tracks),
                          "passed_within_0.5_m": len(passed),
                          "of_those_ended_within_0.5_m": sum(t["end_distance_m"] <= 0.5 for t in passed),
                          "end_distance_m_median": round(float(np.median([t["end_distance_m"] for t in tracks])), 2)
                          if tracks else math.nan,
                          "response": response(sp, est, att)}))


if __name__ == "__main__":
    main()
