"""The pad-speed sweep: where each method stops working as the pad drives faster. The plan (task,
arms, speeds, endpoints, the question) is docs/baselines.md, "Where learning wins: the pad-speed
sweep", with its Amendment 1 (the roof carries the multirotor; the expert flown with and without
``lead_moving_pad``, the leading expert teaching every policy), Amendment 2 (CoL+) and
Amendment 3 (the board inked into the colour pad, ``aruco-disc``), each written before its runs.
Steps, each resumable on its own (a step whose kept output exists is skipped):

    python results/moving-pad/sweep/run.py configs                  # the task's config files, from configs/paper.toml
    python results/moving-pad/sweep/run.py fly precland-px4 0.5     # one arm at one pad speed (m/s)
    python results/moving-pad/sweep/run.py fly-real ardupilot 1.0   # precision landing on a real autopilot's SITL
                                                                    # (--arm expert-lead: the leading expert there)
    python results/moving-pad/sweep/run.py policies 0.5             # Demo@20 / CoL@20 / CoL+@20, P1-P4 x replicates 0-1,
                                                                    # trained at that speed, then each flown on the board
                                                                    # inked into the pad (--board aruco: the first board)
    python results/moving-pad/sweep/run.py verify 0.5               # col experiment --verify: 2 trials rerun
    python results/moving-pad/sweep/run.py records                  # environment.jsonl from the runs' records
    python results/moving-pad/sweep/run.py summarise                # summary.json, table.md, ../sweep.png

Arms: precland-px4, precland-ardupilot (PLND_OPTIONS bit 0 on), their ``-disc`` twins on the
board inked into the pad (Amendment 3), precland-px4-plain (the colour pad: nothing to see),
expert, expert-lead; precland-ardupilot and precland-px4-plain fly a SITL
that run.py starts itself (ArduPilot's PLND_* set over MAVLink; the colour pad under the
companion's ArUco-pad file), see RUN.md. Speeds: 0, 0.25, 0.5, 0.75, 1.0, 1.5. ``--episodes N``
(fly, policies) flies N starts instead of 100 as a check: its episodes go to the runs folder's
checks/, never to episodes/. Run folders go to runs/moving-pad-sweep/ (``--runs`` for another);
what is committed is each arm's and policy's episodes.jsonl (episodes/), each speed's grid lines
(policies/SPEED/) and the summaries.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomllib

from colcommon.logged_run import run_logged

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
EPISODES = HERE / "episodes"
CONFIGS = HERE / "configs"
POLICIES = HERE / "policies"
DEFAULT_RUNS = ROOT / "runs" / "moving-pad-sweep"
PAPER = ROOT / "configs" / "paper.toml"
SPEEDS = ("0", "0.25", "0.5", "0.75", "1.0", "1.5")  # m/s, the pad's speed (the plan's six)
LEVEL = 0.2  # configs/paper.toml's disturbance level: the vehicle drives at level x vehicle_speed_max_m_s
STARTS, FIRST_START = 100, 100_000
PARTICIPANTS = ("P1", "P2", "P3", "P4")
REPLICATES = (0, 1)
CONDITIONS = ("demo", "col", "colplus")  # docs/baselines.md, Amendment 2
INTERACTIONS = 20
WORKERS = 2
PRECLAND = ("--pilot", "precland")
EXPERT = ("--pilot", "expert", "--condition", "demo", "--no-learn")
MAV_PARAM_TYPE_INT8, MAV_PARAM_TYPE_INT16 = 2, 4
MAV_CMD_DO_SET_MODE, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, MAV_RESULT_ACCEPTED = 176, 246, 0
COPTER_GUIDED = 4
# ArduCopter's precision landing on the companion's LANDING_TARGET (as companion/link/dialect.py
# sets it) and AC_PrecLand's moving-target option, PLND_OPTIONS bit 0 (sitl/ardupilot_plnd.py)
PLND_MOVING_TARGET = (("PLND_ENABLED", 1.0, MAV_PARAM_TYPE_INT8), ("PLND_TYPE", 1.0, MAV_PARAM_TYPE_INT8),
                      ("PLND_OPTIONS", 1.0, MAV_PARAM_TYPE_INT16))
READY_WITHIN_S = 120.0  # a reboot (8 s) and the EKF's settling (10 s) in real time, on a busy machine
CONFIG_KINDS = ("colour-pad", "colour-pad-lead", "precland-px4", "precland-ardupilot", "precland-px4-disc",
                "precland-ardupilot-disc")
BOARDS = {"aruco": "precland-px4", "aruco-disc": "precland-px4-disc"}  # the policies' marked pads: their config kind
BOARD_OF_KIND = {"precland-px4": "aruco", "precland-ardupilot": "aruco", "precland-px4-disc": "aruco-disc",
                 "precland-ardupilot-disc": "aruco-disc"}


@dataclass(frozen=True)
class Arm:
    """How one arm flies: who holds the sticks, the companion's config kind, and (for an
    external SITL) the SITL's own config kind, clock, and the parameters set (then a reboot and
    the wait for the vehicle to be ready) before the companion connects."""

    pilot: tuple[str, ...]
    config: str
    sitl_config: str | None = None  # None: col fly starts its own SITL on ``config``
    clock: str = "lockstep"
    params: tuple[tuple[str, float, int], ...] = ()  # name, value, MAV_PARAM_TYPE

    @property
    def external(self) -> bool:
        return self.sitl_config is not None


ARMS: dict[str, Arm] = {
    "precland-px4": Arm(PRECLAND, "precland-px4"),
    # PLND_OPTIONS has no config key (sitl/ardupilot_plnd.py PLND_DEFAULTS are ArduCopter's own):
    # set over MAVLink, as a ground station would, with PLND_ENABLED and PLND_TYPE and the reboot
    # that makes them take effect, before the companion connects (which then finds them set)
    "precland-ardupilot": Arm(PRECLAND, "precland-ardupilot", sitl_config="precland-ardupilot", clock="realtime",
                              params=PLND_MOVING_TARGET),
    # the colour pad: the companion's file has the board (col fly refuses precland without it),
    # the SITL flies the colour pad, so the detector decodes nothing
    "precland-px4-plain": Arm(PRECLAND, "precland-px4", sitl_config="colour-pad"),
    # Amendment 3: the same two arms on the board inked into the colour pad, which the policies see
    "precland-px4-disc": Arm(PRECLAND, "precland-px4-disc"),
    "precland-ardupilot-disc": Arm(PRECLAND, "precland-ardupilot-disc", sitl_config="precland-ardupilot-disc",
                                   clock="realtime", params=PLND_MOVING_TARGET),
    "expert": Arm(EXPERT, "colour-pad"),
    "expert-lead": Arm(EXPERT, "colour-pad-lead"),
}


# ----- config files ------------------------------------------------------------------------------

_HEADER = re.compile(r"^\s*\[([^\[\]]+)\]\s*(#.*)?$")


def toml_value(value: object) -> str:
    """A TOML literal of a bool, number, string or list of them."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML literal for {value!r}")


def set_key(text: str, table: str, key: str, value: object, comment: str = "") -> str:
    """``text`` with ``key = value`` in ``[table]``: replaced where the table has the key, added
    after its last key otherwise, and the table appended only when the file has none (a TOML
    file must not name a table twice)."""
    lines = text.splitlines()
    line = f"{key} = {toml_value(value)}" + (f"  # {comment}" if comment else "")
    start = next((i for i, s in enumerate(lines) if (m := _HEADER.match(s)) and m.group(1).strip() == table), None)
    if start is None:
        return text.rstrip("\n") + f"\n\n[{table}]\n{line}\n"
    end = next((i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    keyed = re.compile(rf"^\s*{re.escape(key)}\s*=")
    hit = next((i for i in range(start + 1, end) if keyed.match(lines[i])), None)
    if hit is not None:
        lines[hit] = line
    else:
        last = max(i for i in range(start, end) if lines[i].strip() and not lines[i].lstrip().startswith("#"))
        lines.insert(last + 1, line)
    return "\n".join(lines) + "\n"


def speed_max(speed: str) -> float:
    """``[sitl.disturbance] vehicle_speed_max_m_s`` that drives the pad at exactly ``speed`` at
    the task's level: sitl/disturbance.py draws the speed as level x maximum, not at random (only
    the direction is uniform), so level x maximum must give the speed to the last bit."""
    value = round(float(speed) / LEVEL, 9)
    if LEVEL * value != float(speed):
        raise ValueError(f"{LEVEL} x {value} is not exactly {speed} m/s in floating point")
    return value


def config_path(kind: str, speed: str) -> Path:
    return CONFIGS / f"{kind}-speed-{speed}.toml"


def policies_config_path(speed: str) -> Path:
    return CONFIGS / f"policies-{speed}.toml"


def header(name: str, speed: str, what: str, written_by: str = "") -> str:
    """The file's opening comment; ``written_by``: the step that writes it, when not ``configs``."""
    made = (f"# Written by `python results/moving-pad/sweep/run.py {written_by}` (rerun that, do not edit).\n#\n"
            if written_by else
            "# Written by `python results/moving-pad/sweep/run.py configs` from configs/paper.toml (rerun that,\n"
            "# do not edit). Below: configs/paper.toml with the sweep's keys set.\n#\n")
    amended = "Amendments" if written_by else "Amendment 1"  # the configs step's files stay as they were written
    return (f"# {name}: the pad-speed sweep (docs/baselines.md, \"Where learning wins\", and its {amended}),\n"
            f"# the pad driving at {speed} m/s straight on, its direction uniform per episode; {what}.\n" + made)


def task_text(paper: str, speed: str) -> str:
    """configs/paper.toml with the pad driving at ``speed`` and the roof carrying the multirotor."""
    text = set_key(paper, "sitl.disturbance", "vehicle_speed_max_m_s", speed_max(speed),
                   f"x level {LEVEL} = {speed} m/s, exactly (the sweep)")
    return set_key(text, "sitl.world", "roof_carries", True, "the sweep's Amendment 1")


def config_texts(paper: str, speed: str, conditions: tuple[str, ...] = CONDITIONS) -> dict[Path, str]:
    """Every config file of one speed: its path and text."""
    task = task_text(paper, speed)
    lead = set_key(task, "companion.pilot", "lead_moving_pad", True, "the leading expert (Amendment 1)")
    aruco = set_key(task, "sitl.camera", "pad_marker", "aruco", "the ArUco board on the pad (sitl/pad_marker.py)")
    disc = set_key(task, "sitl.camera", "pad_marker", "aruco-disc",
                   "the ArUco board inked into the colour pad (sitl/pad_marker.py; Amendment 3)")

    def ardupilot_of(text: str) -> str:
        return set_key(text, "sitl.personality", "autopilot", "ardupilot",
                       "PLND_OPTIONS = 1 (moving target) is set over MAVLink by run.py: no config key")

    ardupilot = ardupilot_of(aruco)
    bodies = {
        "colour-pad": (task, "the colour pad (expert, precland-px4-plain's SITL)"),
        "colour-pad-lead": (lead, "the colour pad, the leading expert (expert-lead)"),
        "precland-px4": (aruco, "the ArUco board, PX4 (precland-px4; the policies flown on the board)"),
        "precland-ardupilot": (ardupilot, "the ArUco board, ArduPilot PLND with the moving-target option"),
        "precland-px4-disc": (disc, "the board inked into the colour pad, PX4 (precland-px4-disc; the policies on it)"),
        "precland-ardupilot-disc": (ardupilot_of(disc), "the board inked into the colour pad, ArduPilot PLND with the "
                                                        "moving-target option"),
    }
    out = {config_path(kind, speed): header(config_path(kind, speed).name, speed, what) + body
           for kind, (body, what) in bodies.items()}
    grid = experiment_text(lead, conditions)
    out[policies_config_path(speed)] = header(policies_config_path(speed).name, speed,
                                              "the policies' grid, taught by the leading expert") + grid
    return out


def experiment_text(text: str, conditions: tuple[str, ...]) -> str:
    """The grid of one speed: P1-P4 x ``conditions`` at 20 interactions x replicates 0-1, 100
    held-out starts from 100000; the other [experiment] keys as configs/paper.toml has them."""
    for key, value, comment in (
        ("participants", list(PARTICIPANTS), "synthetic pilot profiles"),
        ("conditions", list(conditions), "the sweep's policies (docs/baselines.md, Amendment 2: CoL+ beside Demo and CoL)"),
        ("interactions", [INTERACTIONS], "Demo@20, CoL@20"),
        ("seeds", list(REPLICATES), "replicates 0 and 1: 8 trials a condition"),
        ("eval_runs", STARTS, "held-out starts flown by every final policy"),
        ("eval_seed", FIRST_START, "seed of the first held-out start"),
    ):
        text = set_key(text, "experiment", key, value, comment)
    return text


def expected_tables(kind: str, speed: str) -> dict[tuple[str, ...], object]:
    """The keys each config kind must have, by their TOML path (what :func:`check_config` reads)."""
    want: dict[tuple[str, ...], object] = {
        ("sitl", "disturbance", "level"): LEVEL,
        ("sitl", "disturbance", "vehicle_speed_max_m_s"): speed_max(speed),
        ("sitl", "world", "roof_carries"): True,
    }
    if kind in ("colour-pad-lead", "policies"):
        want[("companion", "pilot", "lead_moving_pad")] = True
    if kind in BOARD_OF_KIND:
        want[("sitl", "camera", "pad_marker")] = BOARD_OF_KIND[kind]
    if kind in ("precland-ardupilot", "precland-ardupilot-disc"):
        want[("sitl", "personality", "autopilot")] = "ardupilot"
    if kind == "policies":
        want[("experiment", "interactions")] = [INTERACTIONS]
        want[("experiment", "seeds")] = list(REPLICATES)
        want[("experiment", "eval_runs")] = STARTS
        want[("experiment", "eval_seed")] = FIRST_START
    return want


def check_config(text: str, want: dict[tuple[str, ...], object]) -> None:
    """The file parses as TOML and has every wanted key at its value."""
    data: Any = tomllib.loads(text)
    for keys, value in want.items():
        got: Any = data
        for k in keys:
            got = got.get(k) if isinstance(got, dict) else None
        if got != value:
            raise ValueError(f"{'.'.join(keys)} = {got!r}, wanted {value!r}")


def kind_of(path: Path) -> str:
    return "policies" if path.name.startswith("policies-") else path.name.split("-speed-")[0]


def write_configs(conditions: tuple[str, ...] = CONDITIONS) -> list[Path]:
    """Every speed's config files, each checked before it is written."""
    paper = PAPER.read_text()
    if paper.count(f"level = {LEVEL}") != 1:
        raise SystemExit(f"configs/paper.toml's disturbance level is no longer {LEVEL}: the sweep's speeds assume it")
    CONFIGS.mkdir(parents=True, exist_ok=True)
    written = []
    for speed in SPEEDS:
        for path, text in config_texts(paper, speed, conditions).items():
            check_config(text, expected_tables(kind_of(path), speed))
            path.write_text(text)
            written.append(path)
    return written


def config_conditions(path: Path) -> tuple[str, ...]:
    return tuple(tomllib.loads(path.read_text())["experiment"]["conditions"])


# ----- running ---------------------------------------------------------------------------------------

def col() -> str:
    return _rel(Path(sys.executable).with_name("col"))


def _rel(path: Path) -> str:
    """A path as the commands (run from the repository's root) name it: relative, so the
    records say nothing of the machine's folders."""
    return os.path.relpath(path, ROOT)


def speed_name(text: str) -> str:
    """One of :data:`SPEEDS` (``1`` and ``1.00`` are ``1.0``)."""
    for s in SPEEDS:
        if float(s) == float(text):
            return s
    raise argparse.ArgumentTypeError(f"the sweep's speeds are {', '.join(SPEEDS)} m/s, not {text}")


def kept_path(name: str, episodes: int, runs: Path, planned: int = STARTS) -> Path:
    """Where a run's episodes are kept: episodes/ for the plan's ``planned`` starts, the runs
    folder's checks/ for a smaller check (never committed)."""
    return EPISODES / f"{name}.jsonl" if episodes == planned else runs / "checks" / f"{name}-{episodes}.jsonl"


def _run(cmd: list[str], log: Path) -> None:
    run_logged(cmd, log, ROOT)


def _keep(source: Path, kept: Path) -> None:
    kept.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(source, kept)


def fly_command(arm: str, speed: str, run_dir: Path, episodes: int, external: dict[str, str] | None = None) -> list[str]:
    """The ``col fly`` of one arm at one speed; ``external``: the SITL run.py started (its
    MAVLink, control surface and camera), in the clock the arm flies."""
    spec = ARMS[arm]
    cmd = [col(), "fly", *spec.pilot, "--config", _rel(config_path(spec.config, speed)), "--episodes", str(episodes),
           "--seed", str(FIRST_START), "--run-dir", _rel(run_dir), "--no-pictures"]
    if external is not None:
        cmd += ["--connect", external["connect"], "--simulator", external["simulator"], "--camera", external["camera"],
                "--lockstep" if spec.clock == "lockstep" else "--realtime"]
    return cmd


def fly(arm: str, speed: str, episodes: int, runs: Path) -> None:
    name = f"{arm}-speed-{speed}"
    kept = kept_path(name, episodes, runs)
    if kept.exists():
        print(f"{_rel(kept)} exists: {name} done")
        return
    run_dir = runs / name if episodes == STARTS else runs / "checks" / f"{name}-{episodes}"
    shutil.rmtree(run_dir, ignore_errors=True)
    log = run_dir.parent / f"{run_dir.name}.log"
    if ARMS[arm].external:
        fly_external(arm, speed, run_dir, episodes, log)
    else:
        _run(fly_command(arm, speed, run_dir, episodes), log)
    _keep(run_dir / "episodes.jsonl", kept)
    print(f"kept {_rel(kept)}")


def _pin_children() -> None:
    """The SITL run.py starts gets the numeric profile col's own SITL would inherit from col."""
    from colcommon import numeric_env as ne

    if ne.why_not_pinned(os.environ, platform.machine(), ne.cpu_flags()) is None:
        os.environ.update(ne.PINNED)


def fly_external(arm: str, speed: str, run_dir: Path, episodes: int, log: Path) -> None:
    """Start the SITL as col fly would (companion/app.py vehicle_connection), prepare it (the
    arm's parameters, a reboot, ready), fly, read the parameters back (they must have held), and
    say so in ``external_sitl.json`` beside the run's records."""
    from companion.app import free_udp_port
    from companion.simulator import start_sitl

    spec = ARMS[arm]
    assert spec.sitl_config is not None
    _pin_children()
    port = free_udp_port()
    sitl_config = _rel(config_path(spec.sitl_config, speed))
    sitl = start_sitl(port, clock=spec.clock, config=sitl_config, seed=FIRST_START, nice=0, timeout_s=120.0)
    try:
        connect = f"udpin:127.0.0.1:{port}"
        prepared = prepare_vehicle(connect, spec.params) if spec.params else {}
        external = {"connect": connect, "simulator": f"127.0.0.1:{sitl.control_port}",
                    "camera": str(sitl.ports["camera_uri"])}
        _run(fly_command(arm, speed, run_dir, episodes, external), log)
        after = read_params(connect, [n for n, _, _ in spec.params]) if spec.params else {}
    finally:
        sitl.stop()
    note = {"sitl_config": sitl_config, "clock": spec.clock, "seed": FIRST_START,
            "params_set": {n: v for n, v, _ in spec.params}, **prepared, "params_after_run": after}
    (run_dir / "external_sitl.json").write_text(json.dumps(note, indent=1, sort_keys=True) + "\n")
    wrong = {n: v for n, v, _ in spec.params if after.get(n) != v}
    if wrong:
        raise SystemExit(f"{arm}: after the run the vehicle had {after}, not {note['params_set']}: the arm is not "
                         f"what the plan says; {_rel(run_dir)} kept, episodes not")


REAL_SPEEDUP = {"ardupilot": 5.0, "px4": 4.0}  # as the real-autopilot tests run them (docs/link.md)
REAL_STARTS = 20  # the plan: 20 starts an arm and speed on a real autopilot's SITL
REAL_ARMS = {"precland": PRECLAND, "expert-lead": EXPERT}  # Amendment 4: on the board in the colour pad


def real_config_path(speed: str, arm: str = "precland") -> Path:
    return CONFIGS / f"real-{arm}-speed-{speed}.toml"


def real_config_text(speed: str, arm: str = "precland") -> str:
    """A real autopilot's SITL: the board in the colour pad (Amendment 3) drawn by the rendered
    camera (from the SITL's truth) on a pad that drives as the sweep's does, from each episode's
    hand-over, in the SITL's own wind at the task's level where it has one, the touchdown its
    truth's first ground contact (docs/link.md; Amendment 4); the leading expert for its arm."""
    lead = '\n[companion.pilot]\nlead_moving_pad = true  # the leading expert (Amendment 1)\n' if arm == "expert-lead" else ""
    what = "the rendered camera, the ArUco board in the colour pad" + (", the leading expert" if lead else "")
    return header(real_config_path(speed, arm).name, speed, f"a real autopilot's SITL, {what}",
                  f"fly-real AUTOPILOT {speed} --arm {arm}") + lead + f"""
[companion.session]
clock = "vehicle"  # the autopilot runs faster than real time: steps by its time_boot_ms
pad_ned_m = [0.0, 0.0, 0.0]  # the pad on the autopilot's own ground
start_height_above_pad_m = 8.0  # our SITL's start box
start_xy_range_m = 3.0
autopilot_sim_disturbance = true  # its SITL's wind and turbulence at the level, the rendered pad's drive
touchdown_by_truth_contact = true  # the rendered pad is no surface: first ground contact by the SITL's truth (Amendment 4)

[companion.perception]
camera = "render"

[sitl.camera]
pad_marker = "aruco-disc"

[sitl.world]
vehicle_height_m = 0.0

[sitl.disturbance]
level = {LEVEL}
vehicle_speed_max_m_s = {toml_value(speed_max(speed))}  # x level {LEVEL} = {speed} m/s, exactly (the sweep)
"""


def fly_real(autopilot: str, speed: str, episodes: int, runs: Path, arm: str = "precland") -> None:
    """One arm on a real autopilot's SITL (the plan's "at 0.5 and 1.0 m/s the PX4 precland and the
    expert also fly real PX4 SIH and real ArduCopter with the rendered camera"): started fresh at
    its speed-up; for precision landing ArduCopter's PLND_* with the moving-target option set (and
    rebooted) as in our SITL's arm, then ``col fly --pilot precland`` (the parameters read back
    afterwards); for ``expert-lead`` the leading expert on the same pad."""
    from companion.testing.autopilots import find_autopilots, start_ardupilot, start_px4

    name = f"{arm}-{autopilot}-real-speed-{speed}"
    kept = kept_path(name, episodes, runs, planned=REAL_STARTS)
    if kept.exists():
        print(f"{_rel(kept)} exists: {name} done")
        return
    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    config = real_config_path(speed, arm)
    config.write_text(real_config_text(speed, arm))
    run_dir = runs / name if episodes == REAL_STARTS else runs / "checks" / f"{name}-{episodes}"
    shutil.rmtree(run_dir, ignore_errors=True)
    params = PLND_MOVING_TARGET if autopilot == "ardupilot" and arm == "precland" else ()
    start = start_ardupilot if autopilot == "ardupilot" else start_px4
    with start(root, runs / "autopilots" / name, speedup=REAL_SPEEDUP[autopilot]) as ap:
        prepared = prepare_vehicle(ap.connection, params) if params else {}
        _run([col(), "fly", *REAL_ARMS[arm], "--config", _rel(config), "--episodes", str(episodes), "--seed", str(FIRST_START),
              "--run-dir", _rel(run_dir), "--no-pictures", "--connect", ap.connection], run_dir.parent / f"{run_dir.name}.log")
        after = read_params(ap.connection, [n for n, _, _ in params]) if params else {}
    note = {"autopilot": autopilot, "arm": arm, "speedup": REAL_SPEEDUP[autopilot], "config": _rel(config),
            "params_set": {n: v for n, v, _ in params}, **prepared, "params_after_run": after}
    (run_dir / "external_sitl.json").write_text(json.dumps(note, indent=1, sort_keys=True) + "\n")
    if any(after.get(n) != v for n, v, _ in params):
        raise SystemExit(f"{name}: after the run the vehicle had {after}, not {note['params_set']}; episodes not kept")
    _keep(run_dir / "episodes.jsonl", kept)
    print(f"kept {_rel(kept)}")


def _autopilot_link(connect: str, timeout_s: float) -> Any:
    """A pymavlink connection that has heard the autopilot (component 1)."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(connect, source_system=255, source_component=190)
    if _heard(conn, timeout_s):
        return conn
    conn.close()
    raise SystemExit(f"no autopilot HEARTBEAT on {connect} within {timeout_s:g} s")


def _heard(conn: Any, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
        if msg is not None and msg.get_srcComponent() == 1:
            return True
    return False


def _param_value(conn: Any, name: str, ask: Any, tries: int = 5) -> float:
    """Send ``ask`` until the vehicle answers PARAM_VALUE for ``name``."""
    for _ in range(tries):
        ask()
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None and msg.param_id == name:
                return float(msg.param_value)
    raise SystemExit(f"the vehicle did not answer for {name}")


def _command(conn: Any, command: int, *params: float) -> int | None:
    """COMMAND_LONG to the autopilot; its COMMAND_ACK result, or None when it does not answer
    within 2 s (rebooting: it is silent)."""
    args = (list(params) + [0.0] * 7)[:7]
    conn.mav.command_long_send(1, 1, command, 0, *args)
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        msg = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if msg is not None and msg.command == command:
            return int(msg.result)
    return None


def prepare_vehicle(connect: str, params: tuple[tuple[str, float, int], ...]) -> dict[str, Any]:
    """PARAM_SET each (confirmed by the vehicle's PARAM_VALUE echo; ArduPilot's values go on the
    wire as floats), reboot so that the boot-time ones take effect, and wait until GUIDED is
    accepted (the EKF has settled): so the companion finds them set and reboots nothing, and its
    first episode starts as every other does, not after the settling while the pad drives off."""
    conn = _autopilot_link(connect, READY_WITHIN_S)
    try:
        echoed = {}
        for name, value, kind in params:
            echoed[name] = _param_value(conn, name, lambda n=name, v=value, k=kind: conn.mav.param_set_send(
                1, 1, n.encode(), v, k))
            if echoed[name] != value:
                raise SystemExit(f"the vehicle echoed {name} = {echoed[name]}, not {value}")
        if _command(conn, MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1.0) != MAV_RESULT_ACCEPTED:
            raise SystemExit("the vehicle refused the reboot that makes PLND_TYPE take effect")
        start = time.monotonic()
        while _command(conn, MAV_CMD_DO_SET_MODE, 1.0, COPTER_GUIDED) != MAV_RESULT_ACCEPTED:
            if time.monotonic() - start > READY_WITHIN_S:
                raise SystemExit(f"the vehicle did not accept GUIDED within {READY_WITHIN_S:g} s of its reboot")
            time.sleep(1.0)
        return {"params_echoed": echoed, "rebooted": True, "ready_after_reboot_s": round(time.monotonic() - start, 1)}
    finally:
        conn.close()


def read_params(connect: str, names: list[str], timeout_s: float = 60.0) -> dict[str, float]:
    conn = _autopilot_link(connect, timeout_s)
    try:
        return {n: _param_value(conn, n, lambda n=n: conn.mav.param_request_read_send(1, 1, n.encode(), -1))
                for n in names}
    finally:
        conn.close()


# ----- the policies --------------------------------------------------------------------------------

def with_conditions(path: Path, conditions: tuple[str, ...]) -> None:
    """The grid's conditions set in its config (the fingerprint leaves the grid's extent out,
    so done trials stay done)."""
    text = set_key(path.read_text(), "experiment", "conditions", list(conditions),
                   "the sweep's policies (docs/baselines.md, Amendment 2: CoL+ beside Demo and CoL)")
    check_config(text, {("experiment", "conditions"): list(conditions)})
    path.write_text(text)


def expected_trials(conditions: tuple[str, ...]) -> list[str]:
    return [f"{p}-{c}-{INTERACTIONS:02d}-s{r}" for c in conditions for p in PARTICIPANTS for r in REPLICATES]


def finished_trials(results: Path) -> dict[str, dict[str, Any]]:
    """The last line of every trial that finished (status ok) in a grid's results.jsonl."""
    done: dict[str, dict[str, Any]] = {}
    if not results.exists():
        return done
    for line in results.read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            if row.get("status") == "ok":
                done[row["trial"]["key"]] = row
    return done


def strip_paths(text: str) -> str:
    """Machine paths out of a record: the repository's root goes, and a run folder elsewhere is
    named from its runs/ on."""
    text = text.replace(str(ROOT) + os.sep, "")
    return re.sub(r'"/[^"]*?/(runs/)', r'"\1', text)


def keep_grid(out: Path, speed: str) -> Path:
    """The grid's lines and settings into policies/SPEED/ (with its records: ``--verify`` reruns
    from that folder in the environment they name); a grid trained again (its lines checked equal
    to the kept ones) into policies/SPEED/retrained/, so the first run's records stay as they were."""
    folder = POLICIES / speed
    if (folder / "results.jsonl").exists():
        folder = folder / "retrained"
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("results.jsonl", "timings.jsonl", "config.toml", "experiment.json", "environment.jsonl", "report.md"):
        if (out / name).exists():
            (folder / name).write_text(strip_paths((out / name).read_text()))
    return folder


def policies(speed: str, conditions: tuple[str, ...] | None, episodes: int, runs: Path, workers: int,
             board: str | None = "aruco-disc") -> None:
    """Train the grid of one speed (col experiment resumes it), keep its lines and each trial's
    colour-pad evaluation, then (unless ``board`` is None) fly each final policy on that marked
    pad. A grid trained again (its checkpoints are not committed) must give the committed lines:
    otherwise nothing is kept and the step stops."""
    config = policies_config_path(speed)
    if conditions and config_conditions(config) != conditions:
        with_conditions(config, conditions)
    wanted = expected_trials(config_conditions(config))
    out = runs / f"policies-{speed}"
    # always asked: col experiment itself skips the trials done under these settings (their
    # fingerprint), and redoes those done under others
    _run([col(), "experiment", "--config", _rel(config), "--workers", str(workers), "--out", _rel(out)],
         runs / f"policies-{speed}.log")
    done = finished_trials(out / "results.jsonl")
    check_reproduced(done, speed)
    keep_grid(out, speed)
    missing = [key for key in wanted if key not in done]
    if missing:
        print(f"not finished by the grid (run this step again): {', '.join(missing)}")
    for key in [k for k in wanted if k in done]:
        colour = kept_path(f"{key}-speed-{speed}-colour", STARTS, runs)
        if not colour.exists():
            _keep(out / "trials" / key / "eval_episodes.jsonl", colour)
    if board:  # each evaluation is its own col process: ``workers`` of them at once
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            for evaluated in [pool.submit(eval_marked, key, out / done[key]["final_checkpoint"], speed, episodes, runs, board)
                              for key in wanted if key in done]:
                evaluated.result()  # a failed evaluation stops the step (the others already kept stay)


def check_reproduced(done: dict[str, dict[str, Any]], speed: str) -> None:
    """Every trial the committed grid of ``speed`` has must come out of this run line for line."""
    committed = finished_trials(POLICIES / speed / "results.jsonl")
    differ = [key for key, line in done.items() if key in committed and committed[key] != line]
    if differ:
        raise SystemExit(f"the grid at {speed} m/s trained again differs from policies/{speed}/results.jsonl in "
                         f"{', '.join(differ)}: its policies are not the committed ones; nothing kept")


def eval_command(checkpoint: Path, speed: str, run_dir: Path, episodes: int, board: str = "aruco-disc") -> list[str]:
    return [col(), "eval", _rel(checkpoint), "--config", _rel(config_path(BOARDS[board], speed)),
            "--episodes", str(episodes), "--seed", str(FIRST_START), "--run-dir", _rel(run_dir), "--no-pictures"]


def eval_marked(key: str, checkpoint: Path, speed: str, episodes: int, runs: Path, board: str) -> None:
    """One final policy (``trials/KEY/train/checkpoints/episode_019.npz``) alone on a marked pad."""
    name = f"{key}-speed-{speed}-{board}"
    kept = kept_path(name, episodes, runs)
    if kept.exists():
        return
    run_dir = runs / name if episodes == STARTS else runs / "checks" / f"{name}-{episodes}"
    shutil.rmtree(run_dir, ignore_errors=True)
    _run(eval_command(checkpoint, speed, run_dir, episodes, board), run_dir.parent / f"{run_dir.name}.log")
    _keep(run_dir / "episodes.jsonl", kept)


def verify(speed: str) -> None:
    """``col experiment --verify`` of two trials chosen at random from the kept grid; the
    verdict and its per-trial lines appended to policies/SPEED/verify.jsonl."""
    folder = POLICIES / speed
    cmd = [col(), "experiment", "--verify", _rel(folder), "--trials", "2"]
    done = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL, cwd=ROOT)
    lines = done.stdout.splitlines()
    try:
        verdict = json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        raise SystemExit(f"{' '.join(cmd)} gave no verdict ({done.returncode}):\n{done.stderr[-2000:]}") from None
    verdict["per_trial"] = lines[:-1]
    verdict["exit_code"] = done.returncode
    verdict["command"] = cmd
    with (folder / "verify.jsonl").open("a") as f:
        f.write(strip_paths(json.dumps(verdict, sort_keys=True)) + "\n")
    print(json.dumps({k: verdict.get(k) for k in ("identical", "exit_code")}))


# ----- records -----------------------------------------------------------------------------------

def configs_record() -> None:
    """The configs step's own line in environment.jsonl (the commit its files came from)."""
    from colcommon.numeric_env import append_record

    append_record(HERE, step="configs", command=["results/moving-pad/sweep/run.py", "configs"])


def run_folder_of(kept: Path, runs: Path) -> tuple[Path, str]:
    """The run folder whose records belong to a kept episodes file, and the arm it is tagged
    with: a colour-pad policy evaluation was the grid's (its records are the grid's)."""
    stem = kept.stem
    match = re.fullmatch(r"(.+)-speed-([0-9.]+)-colour", stem)
    if match:
        return runs / f"policies-{match.group(2)}", f"policies-speed-{match.group(2)}"
    return runs / stem, stem


def tagged_records(folder: Path, arm: str) -> list[str]:
    """``folder``'s environment records, each tagged with ``arm`` (and an external SITL's note)."""
    records = folder / "environment.jsonl"
    if not records.exists():
        return []
    note = folder / "external_sitl.json"
    extra = {"external_sitl": json.loads(note.read_text())} if note.exists() else {}
    return [strip_paths(json.dumps({"arm": arm, **extra, **json.loads(line)}, sort_keys=True))
            for line in records.read_text().splitlines() if line.strip()]


def environment_records(runs: Path) -> None:
    """``environment.jsonl`` here: the configs step's lines, then every kept run's records
    (tagged with its arm; a grid's once), machine paths stripped; no line already here is lost."""
    path = HERE / "environment.jsonl"
    old = [line for line in (path.read_text().splitlines() if path.exists() else []) if line.strip()]
    lines = [line for line in old if json.loads(line).get("step") == "configs"]
    seen = set()
    for kept in sorted(EPISODES.glob("*.jsonl")):
        found = run_folder_of(kept, runs)
        if found[1] in seen:
            continue
        seen.add(found[1])
        # an arm's lines already here stay (its run folder gone, or run again: a retrained grid),
        # and its folder's lines not here yet are added
        here = [line for line in old if json.loads(line).get("arm") == found[1]]
        lines += here + [line for line in tagged_records(*found) if line not in here]
    path.write_text("\n".join(lines) + "\n")
    print(f"{len(lines)} records in {_rel(path)}")


# ----- the command line ----------------------------------------------------------------------------

def parse_conditions(text: str) -> tuple[str, ...]:
    from companion.experiment.grid import TRAIN_CONDITIONS

    conditions = tuple(c.strip() for c in text.split(",") if c.strip())
    unknown = [c for c in conditions if c not in TRAIN_CONDITIONS]
    if unknown or not conditions:
        raise argparse.ArgumentTypeError(f"conditions are some of {', '.join(TRAIN_CONDITIONS)}, got {text}")
    return conditions


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=Path, default=DEFAULT_RUNS, help="where the run folders go (default runs/moving-pad-sweep)")
    sub = p.add_subparsers(dest="step", required=True)
    c = sub.add_parser("configs", help="the config files, from configs/paper.toml")
    c.add_argument("--conditions", type=parse_conditions, default=CONDITIONS, help="the grids' conditions, e.g. demo,col,colplus")
    one = sub.add_parser("fly", help="one arm at one speed")
    one.add_argument("arm", choices=tuple(ARMS))
    one.add_argument("speed", type=speed_name)
    one.add_argument("--episodes", type=int, default=STARTS, help="a check: this many starts (kept under the runs folder)")
    real = sub.add_parser("fly-real", help="precision landing or the leading expert on a real autopilot's SITL, the rendered camera")
    real.add_argument("autopilot", choices=tuple(REAL_SPEEDUP))
    real.add_argument("speed", type=speed_name)
    real.add_argument("--arm", choices=tuple(REAL_ARMS), default="precland")
    real.add_argument("--episodes", type=int, default=REAL_STARTS, help="a check: this many starts (kept under the runs folder)")
    pol = sub.add_parser("policies", help="the grid of one speed, then its policies on a marked pad")
    pol.add_argument("speed", type=speed_name)
    pol.add_argument("--conditions", type=parse_conditions, default=None, help="e.g. demo,col,colplus (default: the config's)")
    pol.add_argument("--episodes", type=int, default=STARTS, help="a check: the marked pad's evaluation's starts")
    pol.add_argument("--board", choices=tuple(BOARDS), default="aruco-disc",
                     help="the marked pad the policies fly (default aruco-disc, Amendment 3; aruco hides the colour pad)")
    pol.add_argument("--workers", type=int, default=WORKERS)
    pol.add_argument("--no-aruco", dest="board", action="store_const", const=None,
                     help="keep the grid and its colour-pad evaluations only")
    ver = sub.add_parser("verify", help="col experiment --verify of two trials of one speed's kept grid")
    ver.add_argument("speed", type=speed_name)
    sub.add_parser("records", help="environment.jsonl from the kept runs' records")
    sub.add_parser("summarise", help="summary.json, table.md and ../sweep.png")
    return p


def main() -> None:
    args = parser().parse_args()
    runs = args.runs.resolve()
    os.chdir(ROOT)  # the SITL run.py starts reads its config by the relative path the records name
    if args.step == "configs":
        written = write_configs(args.conditions)
        configs_record()
        print(f"{len(written)} config files in {_rel(CONFIGS)}")
    elif args.step == "fly":
        fly(args.arm, args.speed, args.episodes, runs)
    elif args.step == "fly-real":
        fly_real(args.autopilot, args.speed, args.episodes, runs, args.arm)
    elif args.step == "policies":
        policies(args.speed, args.conditions, args.episodes, runs, args.workers, args.board)
    elif args.step == "verify":
        verify(args.speed)
    elif args.step == "records":
        environment_records(runs)
    else:
        from summarise import main as summarise  # type: ignore[import-not-found]

        summarise()


if __name__ == "__main__":
    main()
