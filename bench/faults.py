"""Reliability and security figures: fuzzing at volume, signing, a lossy link, killed processes,
and (from bench/long_run.py) a long run. Prints one JSON object as its last line.

    nice -n 10 python bench/faults.py                      # the issue's figures (about 20 min)
    nice -n 10 python bench/faults.py --quick              # a smoke run (about 3 min)
    python bench/faults.py --long-result long_run.out      # take the long run's figures from its output
    python bench/faults.py --merge faults.out --long-result long_run.out   # fill them in afterwards

Keys: fuzz_packets (the smaller per-target count), fuzz_crashes, fuzz_hangs,
expert_success_at_10pct_loss (real time, 10 % loss both ways through the seeded proxy),
offboard_loss_to_hold_s (simulation time from the last setpoint of a SIGKILLed companion to
the hold failsafe), samples_lost_on_companion_kill, rss_growth_pct_1000_episodes (or null when
no long run is given), unsigned_commands_obeyed_when_signing_required, machine_ref_rt; details
under "fuzz", "loss_sweep", "kill", "signing" and "long_run".
"""

from __future__ import annotations

import argparse
import json
import logging
import socket
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from machine_ref import machine_ref_rt  # noqa: E402
from pymavlink.dialects.v20 import common as M  # noqa: E402

from colcommon.signing import make_signing  # noqa: E402
from companion.app import RunOptions, run_episodes  # noqa: E402
from companion.config import load_companion_config  # noqa: E402
from companion.simulator import SimulatorClient, running_sitl, start_sitl  # noqa: E402
from companion.testing.fuzz_targets import fuzz_link, fuzz_sitl  # noqa: E402
from companion.testing.kill import ColRun, samples_lost, sigkill, wait_rows  # noqa: E402
from companion.testing.lossy_proxy import LinkFaults, LossyProxy  # noqa: E402

SITL_START_S = 180.0  # a loaded machine starts a SITL slowly


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_until(test: Any, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.02)
    return bool(test())


# ----- fuzzing ----------------------------------------------------------------------------------
def fuzz(packets: int, seed: int) -> dict[str, Any]:
    out = {}
    for name, target in (("sitl", fuzz_sitl), ("link", fuzz_link)):
        t0 = time.monotonic()
        report, after = target(packets, seed=seed)
        out[name] = {"packets": report.packets, "by_kind": report.by_kind, "probes": report.probes,
                     "crashes": report.crashes, "hangs": report.hangs, "slow_probes": report.slow,
                     "notes": report.notes[:5],
                     "wall_s": round(time.monotonic() - t0, 1),
                     **{k: v for k, v in after.items() if k != "stats"}}
        print(f"fuzz {name}: {json.dumps(out[name])}", file=sys.stderr, flush=True)
    return out


# ----- a lossy link -----------------------------------------------------------------------------
def expert_through_proxy(loss: float, delay_s: float, episodes: int, seed: int) -> dict[str, Any]:
    """The scripted expert, real time, through the proxy with ``loss`` both ways."""
    cfg = load_companion_config(None)
    port = free_udp_port()
    faults = LinkFaults(loss=loss, delay_s=delay_s / 2)  # half the latency each way
    with LossyProxy(port, to_companion=faults, to_vehicle=faults, seed=seed) as proxy, \
            running_sitl(proxy.vehicle_port, clock="realtime", seed=seed, timeout_s=SITL_START_S) as sitl, \
            tempfile.TemporaryDirectory(prefix="col-loss-") as work:
        opts = RunOptions(connection=f"udpin:127.0.0.1:{port}", simulator=f"127.0.0.1:{sitl.control_port}",
                          pilot="expert", condition="demo", episodes=episodes, run_dir=Path(work) / "run",
                          learn=False, lockstep=False, seed=seed)
        result = run_episodes(cfg, opts)
        stats = {k: vars(v) for k, v in proxy.stats.items()}
    outcomes: dict[str, int] = {}
    for r in result.records:
        outcomes[r.outcome] = outcomes.get(r.outcome, 0) + 1
    row = {"loss": loss, "extra_latency_s": delay_s, "episodes": len(result.records),
           "success_rate": round(result.successes / max(1, len(result.records)), 3), "outcomes": outcomes,
           "proxy": stats}
    print(f"loss: {json.dumps(row)}", file=sys.stderr, flush=True)
    return row


# ----- killed companion -------------------------------------------------------------------------
def kill_companion(rows_before_kill: int) -> dict[str, Any]:
    port = free_udp_port()
    with running_sitl(port, clock="lockstep", timeout_s=SITL_START_S) as sitl, tempfile.TemporaryDirectory(prefix="col-kill-") as work:
        sim = SimulatorClient("127.0.0.1", sitl.control_port)
        run_dir = Path(work) / "run"
        col = ColRun.start(["--connect", f"udpin:127.0.0.1:{port}", "--simulator", f"127.0.0.1:{sitl.control_port}",
                            "--pilot", "expert", "--condition", "demo", "--no-learn", "--lockstep",
                            "--episodes", "3", "--run-dir", str(run_dir)])
        try:
            if not wait_rows(run_dir / "human.csv", rows_before_kill, 120, col.proc):
                raise RuntimeError(f"col fly wrote no samples: {col.stderr[-5:]}")
            sigkill(col.proc.pid)
            col.proc.wait(10)
        finally:
            col.stop()
        held = wait_until(lambda: sim.truth()["mode"] == "AUTO.LOITER", 30.0)
        t = sim.truth()
        landed = wait_until(lambda: sim.truth()["landed"], 60.0)
        sim.close()
        hold_s = t["failsafe_since_s"] - t["last_setpoint_s"] if held and t["failsafe_since_s"] is not None else None
        return {"held": held, "landed": landed, "offboard_loss_to_hold_s": None if hold_s is None else round(hold_s, 4),
                "samples_lost": samples_lost(run_dir / "human.csv")}


# ----- signing ----------------------------------------------------------------------------------
def unsigned_obeyed(key: bytes, attempts: int) -> dict[str, Any]:
    """Unsigned, wrongly signed and replayed arm/takeoff/mode/setpoint messages at a SITL that
    requires signing, while a signed client keeps talking; how many changed anything."""
    owner = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    owner.bind(("127.0.0.1", 0))
    owner.settimeout(0.2)
    mav = M.MAVLink(None, 245, 191)
    mav.signing = make_signing(key, 3)
    with tempfile.TemporaryDirectory() as work:
        key_file = Path(work) / "k"
        key_file.write_text(key.hex())
        sitl = start_sitl(owner.getsockname()[1], clock="realtime", camera=False, timeout_s=SITL_START_S,
                          extra_args=["--signing-key", str(key_file)])
    sim = SimulatorClient("127.0.0.1", sitl.control_port)
    intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        _, peer = owner.recvfrom(65535)
        owner.sendto(M.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3).pack(mav), peer)
        recorded = bytes(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav))
        owner.sendto(recorded, peer)  # the owner arms ...
        wait_until(lambda: sim.truth()["armed"], 5.0)
        owner.sendto(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav), peer)
        wait_until(lambda: not sim.truth()["armed"], 5.0)  # ... and disarms: the recorded ARM is now a replay
        bad = M.MAVLink(None, 245, 191)
        wrong = M.MAVLink(None, 245, 191)
        wrong.signing = make_signing(bytes(range(1, 33)), 3)
        messages = [
            M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
            M.MAVLink_command_long_message(1, 1, M.MAV_CMD_NAV_TAKEOFF, 0, *[float("nan")] * 7),
            M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0),
            M.MAVLink_set_mode_message(1, 1, 6 << 16),
            M.MAVLink_set_position_target_local_ned_message(0, 1, 1, 8, 0x5C7, 0, 0, 0, 2, 0, -2, 0, 0, 0, 0, 0),
            M.MAVLink_manual_control_message(1, 1000, 0, 1000, 0, 1),
        ]
        sent, obeyed = 0, 0
        before = sim.truth()
        for _ in range(attempts):
            for codec in (bad, wrong):
                for msg in messages:
                    data = bytes(msg.pack(codec))
                    intruder.sendto(data, peer)
                    owner.sendto(data, peer)  # also from the owner's own address
                    sent += 2
            intruder.sendto(recorded, peer)
            sent += 1
            t = sim.truth()
            if t["armed"] or t["mode"] != before["mode"] or abs(t["vehicle_ned"][2] - before["vehicle_ned"][2]) > 0.05:
                obeyed += 1
        return {"messages_sent": sent, "rounds": attempts, "rounds_with_an_effect": obeyed}
    finally:
        sim.close()
        sitl.stop()
        owner.close()
        intruder.close()


class _State:
    """Finished sections, kept in a JSON file so that a stopped run resumes where it was."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self.data: dict[str, Any] = json.loads(path.read_text()) if path is not None and path.exists() else {}

    def section(self, name: str, measure: Any) -> Any:
        if name not in self.data:
            self.data[name] = measure()
            print(f"{name}: {json.dumps(self.data[name])}", file=sys.stderr, flush=True)
            if self.path is not None:
                self.path.write_text(json.dumps(self.data))
        return self.data[name]


def long_result(path: Path | None) -> dict[str, Any] | None:
    if path is None or not path.exists():
        return None
    lines = [x for x in path.read_text().splitlines() if x.startswith("{")]
    return json.loads(lines[-1]) if lines else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small counts: a smoke run")
    ap.add_argument("--fuzz-packets", type=int, default=100_000, help="per target")
    ap.add_argument("--loss-episodes", type=int, default=10, help="real-time episodes at 10 %% loss")
    ap.add_argument("--sweep", action="store_true", help="also 0/5/30 %% loss and 0/100/200 ms latency")
    ap.add_argument("--sweep-episodes", type=int, default=4)
    ap.add_argument("--long-result", type=Path, help="output of bench/long_run.py (its last JSON line)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--state", type=Path, help="keep each finished section here and reuse it when run again "
                    "(a run stopped by a loaded machine resumes); default: none")
    ap.add_argument("--merge", type=Path, help="instead of measuring: this earlier output with --long-result's figures filled in")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    if args.merge is not None:
        merged = long_result(args.merge) or {}
        long = long_result(args.long_result)
        merged.update(rss_growth_pct_1000_episodes=None if long is None else long.get("rss_growth_pct"), long_run=long)
        print(json.dumps(merged))
        return
    if args.quick:
        args.fuzz_packets, args.loss_episodes = 3000, 2
    state = _State(args.state)
    machine_ref = state.section("machine_ref_rt", machine_ref_rt)
    fz = state.section("fuzz", lambda: fuzz(args.fuzz_packets, args.seed))
    signing = state.section("signing", lambda: unsigned_obeyed(bytes(range(100, 132)), 5 if args.quick else 20))
    kill = state.section("kill", lambda: kill_companion(30))
    at10 = state.section("loss_10pct", lambda: expert_through_proxy(0.10, 0.0, args.loss_episodes, args.seed))
    sweep = [at10]
    if args.sweep:
        for loss, delay in ((0.0, 0.0), (0.05, 0.0), (0.30, 0.0), (0.0, 0.1), (0.0, 0.2), (0.10, 0.2)):
            sweep.append(state.section(f"loss_{loss}_{delay}", lambda loss=loss, delay=delay: expert_through_proxy(
                loss, delay, args.sweep_episodes, args.seed)))
    long = long_result(args.long_result)
    print(json.dumps({
        "fuzz_packets": min(v["packets"] for v in fz.values()),
        "fuzz_crashes": sum(v["crashes"] for v in fz.values()),
        "fuzz_hangs": sum(v["hangs"] for v in fz.values()),
        "expert_success_at_10pct_loss": at10["success_rate"],
        "offboard_loss_to_hold_s": kill["offboard_loss_to_hold_s"],
        "samples_lost_on_companion_kill": kill["samples_lost"],
        "rss_growth_pct_1000_episodes": None if long is None else long.get("rss_growth_pct"),
        "unsigned_commands_obeyed_when_signing_required": signing["rounds_with_an_effect"],
        "machine_ref_rt": round(machine_ref, 1),
        "fuzz": fz, "loss_sweep": sweep, "kill": kill, "signing": signing, "long_run": long,
    }))


if __name__ == "__main__":
    main()
