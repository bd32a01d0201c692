"""col-sitl: run the simulated multirotor behind MAVLink until SIGINT/SIGTERM."""

from __future__ import annotations

import ctypes
import json
import logging
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Annotated

import typer

from colcommon.errors import ConfigError
from colcommon.heap import fix_mmap_threshold
from colcommon.signing import read_key
from sitl.config import SitlConfig, load_sitl_config
from sitl.exposure import check_exposure

app = typer.Typer(add_completion=False, help=__doc__)


def _parse_udp(pairs: list[str]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    local, remote = [], []
    for pair in pairs:
        try:
            a, b = pair.split(":")
            local.append(int(a))
            remote.append(int(b))
        except ValueError:
            raise typer.BadParameter(f"--udp takes LOCAL:REMOTE port pairs, got {pair!r}") from None
    return tuple(local), tuple(remote)


def _read_token(path: Path) -> str:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read the control token file {path}: {exc}") from None


def _exit_with_parent() -> None:
    """Ask Linux to send SIGTERM when the parent dies (a killed `col` leaves no SITL behind)."""
    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return  # not Linux: the parent's stop() is the only guard
    if os.getppid() != parent:  # the parent died before the request took effect
        sys.exit(0)


def build_config(
    base: SitlConfig,
    clock: str | None = None,
    speed: float | None = None,
    seed: int | None = None,
    udp: list[str] | None = None,
    tcp: int | None = None,
    camera_port: int | None = None,
    control_port: int | None = None,
    no_camera: bool = False,
    autopilot: str | None = None,
    camera_rate_hz: float | None = None,
    rtp: str | None = None,
) -> SitlConfig:
    """Apply command-line overrides to a config, re-validating the result."""
    data = base.model_dump()
    if clock is not None:
        data["clock"]["mode"] = clock
    if speed is not None:
        data["clock"]["speed"] = speed
    if seed is not None:
        data["world"]["seed"] = seed
    if udp:
        data["network"]["udp_local_ports"], data["network"]["udp_remote_ports"] = _parse_udp(udp)
    if tcp is not None:
        data["network"]["tcp_port"] = None if tcp < 0 else tcp
    if camera_port is not None:
        data["network"]["camera_port"] = camera_port
    if control_port is not None:
        data["network"]["control_port"] = control_port
    if no_camera:
        data["camera"]["enabled"] = False
    if autopilot is not None:
        data["personality"]["autopilot"] = autopilot
    if camera_rate_hz is not None:
        data["camera"]["stream_rate_hz"] = camera_rate_hz
    if rtp is not None:
        data["network"]["rtp_video"] = rtp
    from colcommon.configio import build

    return build(SitlConfig, data, "command-line options")


@app.command()
def run(
    config: Annotated[Path | None, typer.Option(help="TOML config file (\\[sitl] tables); default: built-in paper setting")] = None,
    clock: Annotated[str | None, typer.Option(help="realtime or lockstep")] = None,
    speed: Annotated[float | None, typer.Option(help="real-time speed factor (sim s per wall s)")] = None,
    seed: Annotated[int | None, typer.Option(help="seed for episode starts")] = None,
    udp: Annotated[list[str] | None, typer.Option(help="LOCAL:REMOTE UDP port pair (repeatable; 0 = any free local port)")] = None,
    tcp: Annotated[int | None, typer.Option(help="MAVLink TCP server port (0 = any free, -1 = off)")] = None,
    camera_port: Annotated[int | None, typer.Option(help="camera stream TCP port (0 = any free)")] = None,
    control_port: Annotated[int | None, typer.Option(help="control surface TCP port (0 = any free)")] = None,
    no_camera: Annotated[bool, typer.Option("--no-camera", help="do not render or serve the camera")] = False,
    autopilot: Annotated[str | None, typer.Option(help="personality: px4 (default; lockstep possible) or ardupilot (ArduCopter modes, GUIDED; real time only)")] = None,
    camera_rate: Annotated[float | None, typer.Option("--camera-rate", min=0.1, help="real time: camera frames per second of simulation time (35 for a person's view)")] = None,
    rtp: Annotated[str | None, typer.Option("--rtp", help="also send the camera as H.264 over RTP to HOST:PORT (QGroundControl: 127.0.0.1:5600)")] = None,
    duration: Annotated[float | None, typer.Option(help="stop after this much simulation time (s)")] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="log events")] = False,
    exit_with_parent: Annotated[bool, typer.Option("--exit-with-parent", help="stop when the process that started it dies (Linux)")] = False,
    signing_key: Annotated[Path | None, typer.Option("--signing-key", help="MAVLink 2 signing key file (64 hex digits): sign everything, obey only messages signed with it")] = None,
    host: Annotated[str | None, typer.Option(help="address every server binds (default 127.0.0.1); another needs --allow-remote")] = None,
    allow_remote: Annotated[bool, typer.Option("--allow-remote", help="allow binding a non-loopback address (needs --control-token-file)")] = False,
    control_token_file: Annotated[Path | None, typer.Option("--control-token-file", help="file holding the token every control-surface request must carry")] = None,
) -> None:
    """Start the SITL. Prints one line `READY {json}` with the bound ports once it listens."""
    if exit_with_parent:
        _exit_with_parent()
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(asctime)s %(name)s: %(message)s")
    try:
        cfg = build_config(load_sitl_config(config), clock, speed, seed, udp, tcp, camera_port, control_port, no_camera,
                           autopilot, camera_rate, rtp)
        if host is not None:
            cfg = cfg.model_copy(update={"network": cfg.network.model_copy(update={"host": host})})
        key = read_key(signing_key) if signing_key is not None else None
        token = _read_token(control_token_file) if control_token_file is not None else None
        check_exposure(cfg.network.host, allow_remote, token)
    except ConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    from sitl.server import SitlServer

    try:
        server = SitlServer(cfg, signing_key=key, allow_remote=allow_remote, control_token=token)
    except OSError as exc:
        typer.echo(f"error: cannot open the SITL's sockets ({exc}); is another SITL running? choose other ports", err=True)
        raise typer.Exit(1) from None

    def _stop(signum: int, _frame: object) -> None:
        # A handler runs in the main thread between two bytecodes, possibly inside Event.set: a
        # second signal (the parent's death and a kill) calling server.stop() there waited for
        # the lock its own thread held, forever. The stop goes to a thread of its own instead.
        threading.Thread(target=server.stop, name="stop-on-signal", daemon=True).start()

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    fix_mmap_threshold()  # a long-running SITL's memory stays what it uses (colcommon/heap.py)
    print("READY " + json.dumps(server.ports()), flush=True)
    server.serve(max_sim_s=duration)
    stats = server.stats
    print(json.dumps({"frames": stats.frames, "answered": stats.answered, "timeouts": stats.timeouts, "sim_s": round(server.vehicle.time_s, 3)}), flush=True)


def main() -> None:
    app(prog_name="col-sitl")


if __name__ == "__main__":
    main()
