"""Why an expert run on a real autopilot lands where it does, from the run folder `col fly` wrote
(session.tlog, human.csv, episodes.jsonl) with the rendered camera drawn from the SITL's truth:

    python results/real-autopilots/diagnose.py RUN_DIR > diagnosis.jsonl

(run.py flies into a temporary folder: RUN_DIR is its repeat-0/run-px4 or run-ardupilot). One
line per episode, then one line for the session (``"session": true``). Positions are north/east
metres of the vehicle's local frame (GPS_GLOBAL_ORIGIN), where the pad is at (0, 0).

Per episode:
- ``touchdown``: the true (HIL_STATE_QUATERNION / SIM_STATE, with the origin) and the estimated
  (LOCAL_POSITION_NED) position at the last step: the vectors, not only the distances;
- ``commit``: where the expert committed to its set-down (the scripted expert replayed on the
  recorded observations, the pad's partial flag taken as "touches the border"): the true and
  estimated position, the yaw error, and ``pad_by_truth``: where the expert's view of the pad
  puts it when placed from the true position and heading (near (0, 0) when camera, frames and
  the pad's place agree);
- ``air``: commit to the first downward rangefinder reading <= 0.1 m: seconds, how far the truth
  and the estimate travelled, and the mean of the velocity estimate's error (estimate minus
  truth, as a vector, and its size);
- ``ground``: that contact to the last step: seconds and the true travel (a slide, or a
  touchdown judged late, shows here).

Session: in flight (truth more than 0.3 m above where it stood at the start), the median and
p95 of the horizontal position, velocity and yaw error of the estimate against the truth, and of
the simulated GPS's (GPS_RAW_INT) velocity and position error, with the position error's lag-1
autocorrelation (white noise: about 0).
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from companion.config import PilotConfig
from companion.inputs.expert import ScriptedExpert, view_of
from companion.link.truth import euler_from_quaternion, north_east_m
from companion.msg.observation import Observation
from companion.msg.pad import PadDetection

W_PX, H_PX = 320, 240
CONTACT_M = 0.1
FLYING_M = 0.3  # in flight: the truth this much above where it stood at the start


def in_flight(rows: list[dict]) -> list[bool]:
    """Per row: the truth more than FLYING_M above where the vehicle stood at the start (the
    median of the first 50 rows)."""
    ground = float(np.median([r["td"] for r in rows[:50]]))
    return [r["td"] < ground - FLYING_M for r in rows]


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def read_tlog(path: Path) -> tuple[list[dict], dict[tuple[float, float, float], int], list[tuple]]:
    """Rows at each truth message (with the newest estimate, attitude, rangefinder), the estimate's
    time by its (x, y, vx) to find the recorded steps, and GPS error samples."""
    log = mavutil.mavlink_connection(str(path))
    rows, steps, gps = [], {}, []
    origin = est = att = rng = truth_ne = None
    while (m := log.recv_match(blocking=False)) is not None:
        kind = m.get_type()
        if kind == "GPS_GLOBAL_ORIGIN":
            origin = (m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1e3)
        elif kind == "LOCAL_POSITION_NED":
            est = m
            steps.setdefault((round(m.x, 3), round(m.y, 3), round(m.vx, 3)), m.time_boot_ms)
        elif kind == "ATTITUDE":
            att = m
        elif kind == "DISTANCE_SENSOR":
            rng = m.current_distance / 100.0
        elif kind in ("HIL_STATE_QUATERNION", "SIM_STATE") and origin and est and att:
            if kind == "HIL_STATE_QUATERNION":
                lat, lon, alt, q = m.lat / 1e7, m.lon / 1e7, m.alt / 1e3, tuple(m.attitude_quaternion)
                vn, ve = m.vx / 100.0, m.vy / 100.0
            else:
                lat, lon, alt, q = m.lat_int / 1e7, m.lon_int / 1e7, m.alt, (m.q1, m.q2, m.q3, m.q4)
                vn, ve = m.vn, m.ve
            if lat == 0 and lon == 0:
                continue
            n, e = north_east_m((lat, lon), origin[:2])
            truth_ne = (n, e)
            rows.append(dict(tb=est.time_boot_ms, tn=n, te=e, td=origin[2] - alt, tvn=vn, tve=ve,
                             tyaw=euler_from_quaternion(*q)[2], en=est.x, ee=est.y, evn=est.vx, eve=est.vy,
                             eyaw=att.yaw, rng=rng))
        elif kind == "GPS_RAW_INT" and origin and truth_ne and rows:
            g = north_east_m((m.lat / 1e7, m.lon / 1e7), origin[:2])
            cog = math.radians(m.cog / 100.0)
            gv = (m.vel / 100.0 * math.cos(cog), m.vel / 100.0 * math.sin(cog)) if m.cog != 65535 else None
            r = rows[-1]
            gps.append((g[0] - r["tn"], g[1] - r["te"], None if gv is None else math.hypot(gv[0] - r["tvn"], gv[1] - r["tve"])))
    return rows, steps, gps


def observation(row: dict[str, str]) -> Observation:
    """A recorded step's observation from human.csv (the 15 normalised values undone)."""
    f = {k: float(v) for k, v in row.items() if k != "source"}
    pad = None
    if f["pad_radius"] >= 0:
        u, v = f["pad_u"] * W_PX / 2 + (W_PX - 1) / 2, f["pad_v"] * H_PX / 2 + (H_PX - 1) / 2
        r = f["pad_radius"] * H_PX / 2
        pad = PadDetection(u, v, r, u - r < 0.5 or v - r < 0.5 or u + r > W_PX - 1.5 or v + r > H_PX - 1.5)
    return Observation((f["north_m"] * 10, f["east_m"] * 10, f["down_m"] * 10),
                       (f["roll_rad"] * math.pi, f["pitch_rad"] * math.pi, f["yaw_rad"] * math.pi),
                       (f["vn_m_s"] * 5, f["ve_m_s"] * 5, f["vd_m_s"] * 5),
                       (f["p_rad_s"] * math.pi, f["q_rad_s"] * math.pi, f["r_rad_s"] * math.pi),
                       pad, (W_PX, H_PX), int(round(f["time_s"] * 1000)))


def r3(xy: tuple[float, float] | np.ndarray) -> list[float]:
    return [round(float(v), 3) for v in xy]


def diagnose(run: Path, cfg: PilotConfig) -> list[dict]:
    rows, steps, gps = read_tlog(run / "session.tlog")
    tb = np.array([r["tb"] for r in rows])
    records = [json.loads(line) for line in (run / "episodes.jsonl").read_text().splitlines()]
    by_episode: dict[int, list[dict[str, str]]] = {}
    with (run / "human.csv").open() as fh:
        for row in csv.DictReader(fh):
            by_episode.setdefault(int(row["episode"]), []).append(row)

    def at(t_ms: int) -> int:
        return min(int(np.searchsorted(tb, t_ms)), len(rows) - 1)

    out = []
    for ep, erows in sorted(by_episode.items()):
        rec = next((r for r in records if r["episode"] == ep), {})
        expert = ScriptedExpert(cfg)
        times, commit = [], None
        for row in erows:
            o = observation(row)
            t = steps.get((round(o.position_ned_m[0], 3), round(o.position_ned_m[1], 3), round(o.velocity_ned_m_s[0], 3)))
            times.append(t)
            was = expert._commit.committed
            expert.command(o)
            if expert._commit.committed and not was and t is not None:
                commit = (t, view_of(o, cfg))
        known = [t for t in times if t is not None]
        line: dict = {"episode": ep, "outcome": rec.get("outcome"), "true_distance_m": rec.get("true_touchdown_distance_m"),
                      "distance_m": rec.get("touchdown_distance_m"), "steps_found": f"{len(known)}/{len(times)}"}
        if not known:
            out.append(line)
            continue
        end = at(known[-1])
        line["touchdown"] = {"truth": r3((rows[end]["tn"], rows[end]["te"])), "estimate": r3((rows[end]["en"], rows[end]["ee"]))}
        if commit is not None:
            c = at(commit[0])
            rc, view = rows[c], commit[1]
            cy, sy = math.cos(rc["tyaw"]), math.sin(rc["tyaw"])
            line["commit"] = {"s": round((commit[0] - known[0]) / 1000, 2), "truth": r3((rc["tn"], rc["te"])),
                              "estimate": r3((rc["en"], rc["ee"])), "view_height_m": round(view.height_m, 2),
                              "pad_by_truth": r3((rc["tn"] + cy * view.forward_m - sy * view.right_m,
                                                  rc["te"] + sy * view.forward_m + cy * view.right_m)),
                              "yaw_error_deg": round(math.degrees(wrap(rc["eyaw"] - rc["tyaw"])), 1)}
            k = next((i for i in range(c, end + 1) if rows[i]["rng"] is not None and rows[i]["rng"] <= CONTACT_M), end)
            seg = rows[c:k + 1]
            err = np.array([(r["evn"] - r["tvn"], r["eve"] - r["tve"]) for r in seg])
            line["air"] = {"s": round((rows[k]["tb"] - rc["tb"]) / 1000, 2),
                           "true_travel_m": round(math.hypot(rows[k]["tn"] - rc["tn"], rows[k]["te"] - rc["te"]), 3),
                           "estimate_travel_m": round(math.hypot(rows[k]["en"] - rc["en"], rows[k]["ee"] - rc["ee"]), 3),
                           "velocity_error_mean": r3(err.mean(axis=0)),
                           "velocity_error_size_mean_m_s": round(float(np.hypot(err[:, 0], err[:, 1]).mean()), 3)}
            line["ground"] = {"s": round((rows[end]["tb"] - rows[k]["tb"]) / 1000, 2),
                              "true_travel_m": round(math.hypot(rows[end]["tn"] - rows[k]["tn"], rows[end]["te"] - rows[k]["te"]), 3)}
        out.append(line)

    flying = [r for r, up in zip(rows, in_flight(rows), strict=True) if up]

    def stats(values: list[float], digits: int = 3) -> dict[str, float]:
        return {"median": round(float(np.median(values)), digits), "p95": round(float(np.percentile(values, 95)), digits)}

    session: dict = {"session": True, "in_flight_samples": len(flying)}
    if flying:
        session["estimate_position_error_m"] = stats([math.hypot(r["en"] - r["tn"], r["ee"] - r["te"]) for r in flying])
        session["estimate_velocity_error_m_s"] = stats([math.hypot(r["evn"] - r["tvn"], r["eve"] - r["tve"]) for r in flying])
        session["estimate_yaw_error_deg"] = stats([abs(math.degrees(wrap(r["eyaw"] - r["tyaw"]))) for r in flying], 1)
    if gps:
        g = np.array([(a, b) for a, b, _ in gps])
        session["gps_position_error_m"] = stats(list(np.hypot(g[:, 0], g[:, 1])))
        x = g[:, 0] - g[:, 0].mean()
        session["gps_position_error_lag1_autocorrelation"] = round(float(np.dot(x[1:], x[:-1]) / np.dot(x, x)), 2)
        gv = [v for _, _, v in gps if v is not None]
        if gv:
            session["gps_velocity_error_m_s"] = stats(gv)
    out.append(session)
    return out


def main() -> None:
    for line in diagnose(Path(sys.argv[1]), PilotConfig()):
        print(json.dumps(line))


if __name__ == "__main__":
    main()
