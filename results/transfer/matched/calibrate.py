"""Our SITL's estimate error fitted to a real autopilot's, from run folders `col fly` wrote on it
with the rendered camera drawn from its SITL's truth (session.tlog: LOCAL_POSITION_NED against
HIL_STATE_QUATERNION or SIM_STATE):

    python results/transfer/matched/calibrate.py RUN_DIR [RUN_DIR ...] > FIT.json

In flight (the truth more than 0.3 m above where it stood at the start; a stretch ends at a gap
of more than 0.5 s), the horizontal velocity and position errors of the estimate against the
truth are fitted by sitl/estimate_error.py's ``fit``: the ``[sitl.estimator]`` settings that give
our SITL the same spread and memory. Printed: one JSON object with the fit, the settings, and
the errors' median and p95 speed and distance (those docs/camera.md reports), per run and pooled.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "real-autopilots"))
from diagnose import in_flight, read_tlog  # noqa: E402  (results/real-autopilots/diagnose.py: the same rows and rule)

from sitl.estimate_error import Segment, fit  # noqa: E402

GAP_S = 0.5


def segments(rows: list[dict]) -> list[Segment]:
    """The in-flight stretches of one session's rows (times in s, errors estimate minus truth)."""
    out, current = [], []
    last_t = None
    for r, flying in zip(rows, in_flight(rows), strict=True):
        t = r["tb"] / 1000.0
        if current and (not flying or (last_t is not None and t - last_t > GAP_S)):
            out.append(current)
            current = []
        if flying and (last_t is None or t > last_t):
            current.append((t, r["evn"] - r["tvn"], r["eve"] - r["tve"], r["en"] - r["tn"], r["ee"] - r["te"]))
        last_t = t
    if current:
        out.append(current)
    return [(a[:, 0], a[:, 1:3], a[:, 3:5]) for a in (np.array(s) for s in out if len(s) > 10)]


def spread(segs: list[Segment]) -> dict[str, object]:
    vel = np.concatenate([v for _, v, _ in segs])
    pos = np.concatenate([p for _, _, p in segs])
    speed, off = np.hypot(vel[:, 0], vel[:, 1]), np.hypot(pos[:, 0], pos[:, 1])
    return {"velocity_error_m_s": {"median": round(float(np.median(speed)), 3), "p95": round(float(np.percentile(speed, 95)), 3)},
            "position_error_m": {"median": round(float(np.median(off)), 3), "p95": round(float(np.percentile(off, 95)), 3)},
            "in_flight_s": round(sum(float(t[-1] - t[0]) for t, _, _ in segs), 1), "stretches": len(segs)}


def main() -> None:
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    runs, pooled = {}, []
    for run in map(Path, sys.argv[1:]):
        rows, _, _ = read_tlog(run / "session.tlog")
        segs = segments(rows)
        if not segs:
            raise SystemExit(f"{run}: no flight in its session.tlog with the truth beside the estimate")
        runs[run.name] = spread(segs)
        pooled.extend(segs)
    got = fit(pooled)
    print(json.dumps({"runs": runs, "pooled": spread(pooled),
                      "fit": {k: (round(v, 3) if isinstance(v, float) else v) for k, v in got.__dict__.items()},
                      "sitl_estimator": got.config().model_dump(include={"velocity_error_std_m_s", "velocity_error_tau_s",
                                                                          "position_pull_tau_s"}),
                      "heights_note": "horizontal only; the height and heading errors are not fitted"}))


if __name__ == "__main__":
    main()
