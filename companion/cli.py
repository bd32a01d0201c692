"""col: fly, learn and evaluate. Without --connect, each command starts the SITL for you."""

from __future__ import annotations

import contextlib
import faulthandler
import json
import logging
import os
import signal
import statistics
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from tqdm import tqdm

from companion.errors import ColError, ConfigError
from companion.statistics import wilson_interval

app = typer.Typer(add_completion=False, help=__doc__, no_args_is_help=True)

ConfigOpt = Annotated[Path | None, typer.Option("--config", "-c", help="TOML config (\\[companion] and \\[sitl] tables); default: the paper's setting")]
ConnectOpt = Annotated[str | None, typer.Option("--connect", help="MAVLink connection (udpin:0.0.0.0:14540, tcp:host:port, /dev/ttyACM0,57600); default: start the SITL")]
SimulatorOpt = Annotated[str | None, typer.Option("--simulator", help="HOST:PORT of an external SITL's control surface (episode resets, ground truth)")]
SeedOpt = Annotated[int | None, typer.Option(help="seed of the first episode (episode i uses seed + i)")]
RunDirOpt = Annotated[Path | None, typer.Option("--run-dir", help="where to write dataset, checkpoints, logs (default: runs/<time>-<condition>)")]
VerboseOpt = Annotated[bool, typer.Option("--verbose", "-v", help="log what happens")]
PicturesOpt = Annotated[bool, typer.Option("--pictures/--no-pictures", help="write flight.png (every track from above) and the last episode's episode_NNN.mp4 (camera with HUD) into the run folder")]


def _setup(verbose: bool) -> None:
    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    signal.signal(signal.SIGTERM, _terminate)
    if hasattr(signal, "SIGUSR1"):  # `kill -USR1 PID`: where every thread is, on stderr (a hang's report)
        with contextlib.suppress(AttributeError, ValueError, OSError, RuntimeError):  # a stderr with no file
            faulthandler.register(signal.SIGUSR1, all_threads=True)


def _terminate(signum: int, _frame: object) -> None:
    """SIGTERM unwinds like Ctrl-C, so the SITL we started stops and open files are closed."""
    raise KeyboardInterrupt


def _interrupted(where: Path | None) -> typer.Exit:
    folder = f" in {where}" if where is not None else " in the run folder"
    typer.echo(f"interrupted: the dataset and the checkpoints of finished episodes are kept{folder}", err=True)
    return typer.Exit(130)


@contextlib.contextmanager
def _flight_exits(run_dir: Path | None) -> Iterator[None]:
    """How a command that flies episodes ends on an error (exit 2, what went wrong) or on Ctrl-C
    (exit 130, where the finished episodes are kept)."""
    try:
        yield
    except ColError as exc:
        raise _fail(exc) from None
    except KeyboardInterrupt:
        raise _interrupted(run_dir) from None


def _load(config: Path | None, camera: str | None = None):  # type: ignore[no-untyped-def]
    """The companion's config of ``--config``, with ``--camera`` (when given) as its camera."""
    from companion.config import load_companion_config

    cfg = load_companion_config(config)
    if camera is not None:
        cfg = cfg.model_copy(update={"perception": cfg.perception.model_copy(update={"camera": camera})})
    return cfg


@contextlib.contextmanager
def _episode_bar(total: int, label: str, done: int = 0) -> Iterator[tqdm]:
    """A progress bar of ``total`` episodes (``done`` of them already), closed afterwards."""
    bar = tqdm(total=total, initial=min(done, total), desc=label, unit="ep", leave=False, disable=None)
    try:
        yield bar
    finally:
        bar.close()


def _run(cfg, opts, label: str):  # type: ignore[no-untyped-def]
    from companion.app import run_episodes

    with _episode_bar(opts.episodes or cfg.session.episodes, label) as bar:
        def on_episode(record) -> None:  # type: ignore[no-untyped-def]
            bar.update(1)
            bar.set_postfix(outcome=record.outcome, success=record.success, samples=record.dataset_size)

        return run_episodes(cfg, opts, on_episode)


def _fail(exc: Exception) -> typer.Exit:
    typer.echo(f"error: {exc}", err=True)
    return typer.Exit(2)


@app.command()
def fly(
    connect: ConnectOpt = None,
    simulator: SimulatorOpt = None,
    camera: Annotated[str | None, typer.Option(help='camera source: "auto" (advertised by the vehicle), "render" (our pad world drawn from the vehicle\'s telemetry), colf://host:port, device index, file, URL, or "none" (test mode: pad never visible)')] = None,
    pilot: Annotated[str, typer.Option(help="who holds the sticks: expert (scripted), manual (ground station MANUAL_CONTROL), gamepad, none; or precland: the autopilot's own precision landing on the companion's LANDING_TARGET (no learning; needs an ArUco board, \\[sitl.camera] pad_marker = \"aruco\" or \"aruco-disc\", e.g. --config configs/precland.toml)")] = "expert",
    checkpoint: Annotated[Path | None, typer.Option(help="start from this policy instead of a fresh random one")] = None,
    episodes: Annotated[int | None, typer.Option(min=1, help="number of episodes (default from config)")] = None,
    condition: Annotated[str, typer.Option(help="demo (person flies), int (person intervenes), col (half each), colplus (CoL with the learner switches the ablation supported), ask (half each; the policy holds and asks for help when unsure, needs \\[companion.learner] ensemble_members >= 2), eval (policy alone)")] = "demo",
    config: ConfigOpt = None,
    seed: SeedOpt = None,
    run_dir: RunDirOpt = None,
    learn: Annotated[bool, typer.Option(help="train the policy on the person's samples while flying")] = True,
    lockstep: Annotated[bool | None, typer.Option("--lockstep/--realtime", help="answer the SITL's frames (lockstep) or pace by the wall clock; default: lockstep for a synthetic pilot in our own SITL")] = None,
    signing_key: Annotated[Path | None, typer.Option("--signing-key", help="MAVLink 2 signing key file (64 hex digits): sign everything, trust only signed messages; a SITL started here requires it too")] = None,
    pictures: PicturesOpt = True,
    verbose: VerboseOpt = False,
) -> None:
    """Fly episodes: the person (or scripted expert) demonstrates or intervenes; the policy learns."""
    _setup(verbose)
    from companion.app import RunOptions

    with _flight_exits(run_dir):
        cfg = _load(config, camera)
        if signing_key is not None:
            cfg = cfg.model_copy(update={"link": cfg.link.model_copy(update={"signing_key_file": str(signing_key)})})
        opts = RunOptions(connection=connect, simulator=simulator, pilot=pilot, condition=condition, episodes=episodes, checkpoint=checkpoint,
                          run_dir=run_dir, config_path=config, seed=seed, learn=learn, lockstep=lockstep, pictures=pictures)
        result = _run(cfg, opts, f"fly {condition}")
    for r in result.records:
        success = "unknown" if r.success is None else r.success
        typer.echo(f"episode {r.episode:3d} {r.phase:13s} {r.outcome:9s} success={success} "
                   f"steps={r.steps} human_samples={r.human_samples} interventions={r.interventions}"
                   + (f" touchdown {r.touchdown_distance_m:.2f} m" if r.touchdown_distance_m is not None else ""))
    typer.echo(f"dataset: {result.run_dir / 'human.csv'} ({result.dataset_size} samples); checkpoints: {result.run_dir / 'checkpoints'}")
    typer.echo(json.dumps(result.summary()))


def evaluate(cfg, checkpoint: Path, episodes: int, seed: int, run_dir: Path | None, config: Path | None,  # type: ignore[no-untyped-def]
             connection: str | None = None, simulator: str | None = None, pictures: bool = False) -> dict:
    """Fly ``checkpoint`` alone on seeded starts; success rate with a 95 % interval (None where
    success cannot be judged: a vehicle without the SITL's ground truth)."""
    from companion.app import RunOptions

    opts = RunOptions(connection=connection, simulator=simulator, pilot="none", condition="eval", episodes=episodes,
                      checkpoint=checkpoint, run_dir=run_dir, config_path=config, seed=seed, learn=False,
                      record=False, lockstep=None if connection else True,
                      pictures=pictures)
    result = _run(cfg, opts, "eval")
    n, k, judged = len(result.records), result.successes, result.judged
    lo, hi = wilson_interval(k, judged)
    distances = [r.touchdown_distance_m for r in result.records if r.touchdown_distance_m is not None]
    true = [r.true_touchdown_distance_m for r in result.records if r.true_touchdown_distance_m is not None]
    return {
        "episodes": n,
        "successes": k if judged else None,
        "success_rate": round(k / judged, 4) if judged else None,
        "success_unknown": n - judged,
        "ci95": [round(lo, 4), round(hi, 4)] if judged else None,
        "touchdown_distance_m_median": round(statistics.median(distances), 3) if distances else None,
        "true_touchdown_distance_m_median": round(statistics.median(true), 3) if true else None,
        "touchdowns": len(distances),
        "timeouts": sum(r.outcome == "timeout" for r in result.records),
        "run_dir": str(result.run_dir),
    }


@app.command("eval")
def eval_cmd(
    checkpoint: Annotated[Path, typer.Argument(help="a checkpoint written by col fly / col demo")],
    connect: ConnectOpt = None,
    simulator: SimulatorOpt = None,
    camera: Annotated[str | None, typer.Option(help='camera source: "auto", "render" (our pad world drawn from the vehicle\'s telemetry), colf://host:port, device index, file, URL, or "none" (test mode: pad never visible)')] = None,
    episodes: Annotated[int, typer.Option(min=1, help="evaluation episodes")] = 20,
    config: ConfigOpt = None,
    seed: Annotated[int, typer.Option(help="seed of the first start (held-out starts use a different range than training)")] = 100_000,
    run_dir: RunDirOpt = None,
    pictures: PicturesOpt = True,
    verbose: VerboseOpt = False,
) -> None:
    """Fly a policy alone (in the SITL, lockstep; or on the vehicle --connect names) and report its success rate."""
    _setup(verbose)
    with _flight_exits(run_dir):
        report = evaluate(_load(config, camera), checkpoint, episodes, seed, run_dir, config, connect, simulator,
                          pictures)
    if report["success_rate"] is None:
        typer.echo(f"success unknown for all {report['episodes']} episodes (no ground truth); "
                   f"{report['touchdowns']} touchdowns, median estimated distance {report['touchdown_distance_m_median']} m")
    else:
        typer.echo(f"success {report['successes']}/{report['episodes'] - report['success_unknown']} = "
                   f"{report['success_rate']:.0%} (95% CI {report['ci95'][0]:.0%}-{report['ci95'][1]:.0%}); "
                   f"median touchdown distance {report['touchdown_distance_m_median']} m")
    typer.echo(json.dumps(report))


@app.command("camera-bridge")
def camera_bridge_cmd(
    connect: Annotated[str, typer.Option("--connect", help="MAVLink connection of the bridge's own (PX4's ground-station link: udpin:0.0.0.0:14550)")],
    host: Annotated[str, typer.Option(help="address the colf:// stream is served on")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port of the colf:// stream (0: any free port)")] = 5600,
    rtp: Annotated[str, typer.Option(help="also send H.264 over RTP to HOST:PORT (a ground station: 127.0.0.1:5600)")] = "",
    config: ConfigOpt = None,
    verbose: VerboseOpt = False,
) -> None:
    """A camera for an autopilot that has none: the pad world rendered from the vehicle's telemetry.

    Serves colf://HOST:PORT for `col fly --camera colf://HOST:PORT`; the pad is at
    \\[companion.session] pad_ned_m of the vehicle's local frame, on the ground vehicle of \\[sitl.world]
    (set vehicle_height_m = 0 where the autopilot's own ground is all there is). Ctrl-C stops."""
    _setup(verbose)
    from companion.vision.bridge import run_bridge

    try:
        run_bridge(connect, config, host, port, rtp, on_ready=lambda uri: typer.echo(f"CAMERA {uri}"))
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    except (ColError, ValueError, OSError) as exc:
        raise _fail(exc) from exc


@app.command("export")
def export_cmd(
    checkpoint: Annotated[Path, typer.Argument(help="a checkpoint written by col fly / col demo")],
    format: Annotated[str, typer.Option("--format", help="onnx (checked with ONNX Runtime; TensorRT untested; needs the onnx extra) or npz (the checkpoint format, read by col fly and numpy.load)")] = "onnx",
    opset: Annotated[int, typer.Option("--opset", help="ONNX opset (13 or newer)")] = 17,
    out: Annotated[Path | None, typer.Option("--out", help="file to write (default: beside the checkpoint, .onnx or .export.npz)")] = None,
) -> None:
    """Write a policy for another runtime: input obs \\[batch, 15] in raw units, output actions \\[batch, 4] in (-1, 1)."""
    from companion.learning.export import export_checkpoint

    try:
        written = export_checkpoint(checkpoint, format, out, opset)
    except ColError as exc:
        raise _fail(exc) from None
    typer.echo(json.dumps({"format": format, "opset": opset if format == "onnx" else None, "path": str(written)}))


@app.command()
def demo(
    demonstrations: Annotated[int, typer.Option(min=1, help="episodes the scripted expert flies")] = 3,
    interventions: Annotated[int, typer.Option(min=0, help="episodes the policy flies with the expert intervening")] = 3,
    eval_episodes: Annotated[int, typer.Option("--eval-episodes", min=1, help="episodes the final policy flies alone")] = 10,
    config: ConfigOpt = None,
    run_dir: RunDirOpt = None,
    pictures: PicturesOpt = True,
    verbose: VerboseOpt = False,
) -> None:
    """A short Cycle-of-Learning session in the SITL: demonstrate, intervene, evaluate."""
    _setup(verbose)
    from companion.app import RunOptions, default_run_dir, run_episodes, write_pictures
    from companion.pictures.recorder import FlightRecorder

    with _flight_exits(run_dir):
        cfg = _load(config)
        root = run_dir or default_run_dir(cfg, "demo")
        recorder = FlightRecorder() if pictures else None  # one picture of both training runs
        typer.echo(f"Cycle-of-Learning demo in {root}: {demonstrations} demonstrations, {interventions} "
                   f"interventions, then {eval_episodes} evaluation episodes of the policy alone.")
        demo_opts = RunOptions(pilot="expert", condition="demo", episodes=demonstrations, run_dir=root / "train",
                               config_path=config)
        trained = run_episodes(cfg, demo_opts, control=recorder)
        last_episode = trained.records[-1].episode  # a resumed --run-dir numbers episodes on
        last = trained.run_dir / "checkpoints" / f"episode_{last_episode:03d}.npz"
        if interventions:
            int_opts = RunOptions(pilot="expert", condition="int", episodes=interventions, run_dir=root / "train",
                                  checkpoint=last, config_path=config, seed=cfg.session.seed + last_episode + 1,
                                  first_episode=last_episode + 1)
            more = run_episodes(cfg, int_opts, control=recorder)
            trained.records += more.records
            trained.dataset_size = more.dataset_size
            last = more.run_dir / "checkpoints" / f"episode_{more.records[-1].episode:03d}.npz"
        if recorder is not None:
            write_pictures(recorder, trained, cfg, "demo")
        report = evaluate(cfg, last, eval_episodes, 100_000, root / "eval", config, pictures=pictures)
    for r in trained.records:
        typer.echo(f"  train episode {r.episode} {r.phase:13s} {r.outcome:9s} success={r.success} human_samples={r.human_samples} interventions={r.interventions}")
    typer.echo(f"learned from {trained.dataset_size} human samples "
               f"({sum(r.interventions for r in trained.records)} interventions)")
    typer.echo(f"final policy alone: {report['successes']}/{report['episodes']} landings on the pad "
               f"(95% CI {report['ci95'][0]:.0%}-{report['ci95'][1]:.0%})")
    typer.echo(f"dataset: {root / 'train' / 'human.csv'}\ncheckpoints: {root / 'train' / 'checkpoints'}\nfinal policy: {last}")
    typer.echo(json.dumps({"human_samples": trained.dataset_size, "train_episodes": len(trained.records),
                           "eval_episodes": report["episodes"], "eval_successes": report["successes"],
                           "success_rate": report["success_rate"], "final_checkpoint": str(last)}))


@app.command()
def console(
    connect: ConnectOpt = None,
    simulator: SimulatorOpt = None,
    host: Annotated[str, typer.Option(help="address the page is served on (127.0.0.1: this machine only)")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="HTTP port (0: any free port)")] = 8765,
    allow_remote: Annotated[bool, typer.Option("--allow-remote", help="allow a --host other than loopback (needs --token-file)")] = False,
    token_file: Annotated[Path | None, typer.Option("--token-file", help="file holding the token the page and its socket must carry (?token=...)")] = None,
    allow_host: Annotated[list[str] | None, typer.Option("--allow-host", help="with --allow-remote: a name other machines open the page by (repeatable); requests for any other Host are refused")] = None,
    rtp: Annotated[str, typer.Option(help="also send the camera as H.264 over RTP to HOST:PORT (a ground station: 127.0.0.1:5600)")] = "",
    config: ConfigOpt = None,
    seed: SeedOpt = None,
    run_dir: RunDirOpt = None,
    camera: Annotated[str | None, typer.Option(help='camera source: "auto" (advertised by the vehicle), colf://host:port, device index, file or URL')] = None,
    camera_rate: Annotated[float, typer.Option("--camera-rate", min=1.0, help="frames per second of our SITL's camera for the page")] = 35.0,
    start: Annotated[str | None, typer.Option("--start", help="start a run at once: CONDITION:EPISODES, e.g. col:8 (else press Start in the page)")] = None,
    learn: Annotated[bool, typer.Option(help="train the policy on the person's samples while flying")] = True,
    pictures: PicturesOpt = True,
    verbose: VerboseOpt = False,
) -> None:
    """The pilot console in a browser: see the camera, fly with a gamepad, intervene, watch the policy learn.

    Serves a page at http://HOST:PORT/ and flies the SITL (started in real time for each run) or
    the vehicle of --connect. The page's gamepad (Xbox layout) or keyboard is the person's input."""
    _setup(verbose)
    from companion.app import PERSON_CONDITIONS, default_run_dir
    from companion.console.access import allowed_hosts, check_console_exposure
    from companion.console.server import run_console
    from companion.console.session import ConsoleOptions, ConsoleSession

    try:
        token = _read_secret(token_file, "token") if token_file is not None else None
        check_console_exposure(host, allow_remote, token)  # before any SITL or socket
        if allow_host and not allow_remote:
            raise typer.BadParameter("--allow-host names other machines use: it needs --allow-remote")
        hosts = allowed_hosts(host, allow_remote, tuple(allow_host or ()))
        if rtp:
            from sitl.rtp import parse_destination

            try:
                parse_destination(rtp)
            except ValueError as exc:
                raise typer.BadParameter(str(exc), param_hint="--rtp") from None
        cfg = _load(config, camera)
        autostart = None
        if start is not None:
            cond, _, count = start.partition(":")
            if cond not in PERSON_CONDITIONS or not count.isdigit() or int(count) < 1:
                raise typer.BadParameter(f"--start takes CONDITION:EPISODES with one of {', '.join(PERSON_CONDITIONS)}, "
                                         f"got {start!r}")
            autostart = (cond, int(count))
        opts = ConsoleOptions(run_dir=run_dir or default_run_dir(cfg, "console"), connection=connect, simulator=simulator,
                              config_path=config, camera_rate_hz=camera_rate, seed=seed, learn=learn, pictures=pictures,
                              rtp=rtp)

        def ready(url: str) -> None:
            url = f"{url}?token={token}" if token else url
            typer.echo(f"CONSOLE {url}", err=False)
            typer.echo(f"open {url} in a browser; runs write to {opts.run_dir}; Ctrl-C stops", err=True)

        run_console(lambda publish, frame: ConsoleSession(cfg, opts, publish, frame), host, port, ready, autostart,
                    token, hosts)
    except ColError as exc:
        raise _fail(exc) from None
    except OSError as exc:
        raise _fail(ColError(f"cannot serve the console on {host}:{port}: {exc}; choose another --port")) from None


@app.command()
def study(
    participant: Annotated[str, typer.Option("--participant", help="the participant's id: S01, S02, ... (the number picks the counterbalanced order of conditions)")],
    out: Annotated[Path, typer.Option("--out", help="the participant's study folder (results.jsonl, questionnaire.jsonl, trials/, practice/); run again on it to resume")],
    config: Annotated[Path | None, typer.Option("--config", "-c", help="experiment TOML whose task, evaluation (eval_runs, eval_seed) and learner the trials use (default: configs/paper.toml)")] = None,
    interactions: Annotated[int, typer.Option(min=1, max=100, help="episodes per condition block (the grid's interaction count)")] = 8,
    practice: Annotated[int, typer.Option(min=0, max=20, help="practice demonstrations before the first block (not a trial)")] = 2,
    replicate: Annotated[int, typer.Option(min=0, help="the grid replicate whose training starts the trials fly")] = 0,
    col_plus: Annotated[bool, typer.Option("--col-plus", help="CoL+ as a fourth condition block (a Williams square of four orders)")] = False,
    port: Annotated[int, typer.Option(min=0, max=65535, help="HTTP port on 127.0.0.1 (0: any free port)")] = 8765,
    pictures: PicturesOpt = False,
    verbose: VerboseOpt = False,
) -> None:
    """The paper's protocol for a real person through the console (docs/study.md): practice, then
    Demo, Int and CoL (and CoL+ with --col-plus) in a counterbalanced order, each a trial written as the grid writes it
    (its final policy flown alone on the held-out starts), a NASA-TLX after each block."""
    _setup(verbose)
    from companion.console.server import run_console
    from companion.console.session import ConsoleOptions, ConsoleSession
    from companion.console.study import ConsoleStudy
    from companion.experiment.grid import load_experiment
    from companion.experiment.study import StudyFolder, StudyPlan

    try:
        path = config or find_config("paper.toml")
        setup = load_experiment(path)
        folder = StudyFolder(out, StudyPlan(participant, interactions, practice, replicate, col_plus)).open()
        conducted = ConsoleStudy(folder, setup)
        opts = ConsoleOptions(run_dir=out / "practice", config_path=path, pictures=pictures)

        def ready(url: str) -> None:
            typer.echo(f"CONSOLE {url}", err=False)
            typer.echo(f"open {url} in a browser: participant {participant}, conditions in the order "
                       f"{', '.join(folder.plan.order)}; the study writes to {out}; Ctrl-C stops (run again to resume)",
                       err=True)

        run_console(lambda publish, frame: ConsoleSession(setup.companion, opts, publish, frame, conducted),
                    "127.0.0.1", port, ready)
    except ColError as exc:
        raise _fail(exc) from None
    except OSError as exc:
        raise _fail(ColError(f"cannot serve the study's console on 127.0.0.1:{port}: {exc}; choose another --port")) from None


@app.command("study-report")
def study_report(
    folders: Annotated[list[Path], typer.Argument(help="participants' study folders (col study --out)")],
    out: Annotated[Path, typer.Option("--out", help="folder for report.md and the plots")],
) -> None:
    """The grid's report (tables, paired statistics, plots) over participants' study folders,
    to set beside a synthetic grid's report."""
    from companion.experiment.report import write_report
    from companion.experiment.results import ResultsFile

    try:
        results = []
        for folder in folders:
            path = folder / "results.jsonl"
            if not path.is_file():
                raise ConfigError(f"{folder} has no results.jsonl: give the folders `col study --out` wrote")
            results += ResultsFile(path).load()
        if not results:
            raise ConfigError("no finished trial in these folders yet")
        report = write_report(results, out)
    except ColError as exc:
        raise _fail(exc) from None
    typer.echo(report.read_text())
    typer.echo(json.dumps({"trials": len(results), "report": str(report)}))


def _read_secret(path: Path, what: str) -> str:
    try:
        return path.read_text().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ColError(f"cannot read the {what} file {path}: {exc}") from None


@app.command()
def experiment(
    config: Annotated[Path | None, typer.Option("--config", "-c", help="experiment TOML: the \\[experiment] grid plus \\[companion]/\\[sitl] tables (default: configs/experiment.toml)")] = None,
    workers: Annotated[int | None, typer.Option(min=1, help="trials side by side, each with its own SITL (default: the number of CPUs)")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="results folder; run again with the same folder to resume (default: runs/<config name>)")] = None,
    quick: Annotated[bool, typer.Option("--quick", help="a smoke run: configs/experiment_quick.toml unless --config is given")] = False,
    backend: Annotated[str, typer.Option("--backend", help="process: local worker processes; ray: Ray tasks on a cluster (pip install '.\\[cluster]')")] = "process",
    address: Annotated[str | None, typer.Option("--address", help="with --backend ray: the cluster's address (HOST:PORT of `ray start --head`); default: a local instance")] = None,
    verify: Annotated[Path | None, typer.Option("--verify", help="instead: rerun --trials finished trials of this results folder, chosen at random, and compare their lines byte for byte")] = None,
    trials: Annotated[int | None, typer.Option("--trials", min=1, help="with --verify: how many trials to rerun (default 2)")] = None,
    seed: Annotated[int | None, typer.Option("--seed", help="with --verify: which trials are chosen (default: at random)")] = None,
    trial: Annotated[list[str] | None, typer.Option("--trial", help="with --verify: rerun this trial (its key, e.g. P3-col-04-s3; repeat for more) instead of --trials at random")] = None,
    keep: Annotated[Path | None, typer.Option("--keep", help="with --verify: keep the rerun trials' folders (dataset, checkpoints, evaluation episodes) in this new or empty folder")] = None,
    verbose: VerboseOpt = False,
) -> None:
    """The paper's experiment with synthetic participants: every trial of the grid, then a
    report (Markdown table beside the paper's numbers, PNG plots) in the results folder."""
    _setup(verbose)
    if verify is not None:
        _verify(verify, trials or 2, seed, trial or [], keep)
        return
    from companion.experiment.grid import load_experiment
    from companion.experiment.report import write_report
    from companion.experiment.runner import run_grid

    try:
        _refuse_verify_options(trials, seed, trial, keep)
        _check_backend(backend, address)  # before anything is written into --out
        path = config or find_config("experiment_quick.toml" if quick else "experiment.toml")
        out_dir = out or Path("runs") / path.stem
        setup = load_experiment(path)
        results = run_grid(setup, out_dir, workers or os.cpu_count() or 1, backend=backend,  # type: ignore[arg-type]
                           address=address)
        report = write_report(results, out_dir)
    except ColError as exc:
        raise _fail(exc) from None
    except KeyboardInterrupt:
        typer.echo(f"interrupted: finished trials are kept in {out_dir / 'results.jsonl'}; run again to resume", err=True)
        raise typer.Exit(130) from None
    typer.echo(report.read_text())
    typer.echo(json.dumps({"trials": len(results), "report": str(report), "results": str(out_dir / "results.jsonl")}))


def _refuse_verify_options(trials: int | None, seed: int | None, trial: list[str] | None,
                           keep: Path | None = None) -> None:
    """``--trials``, ``--seed``, ``--trial`` and ``--keep`` say what ``--verify`` reruns and keeps:
    given without it they would be ignored, and the whole grid would run instead of what was asked for."""
    options = (("--trials", trials), ("--seed", seed), ("--trial", trial or None), ("--keep", keep))
    given = [name for name, value in options if value is not None]
    if given:
        raise ConfigError(f"{', '.join(given)} only apply with --verify RESULTS_DIR (which trials to rerun); "
                          "to run the grid, leave them out")


def _check_backend(backend: str, address: str | None) -> None:
    from typing import get_args

    from companion.experiment.runner import Backend

    names = get_args(Backend)
    if backend not in names:
        raise ConfigError(f"unknown --backend {backend!r}; use {' or '.join(names)}")
    if address is not None and backend != "ray":
        raise ConfigError("--address is for --backend ray")


def find_config(name: str) -> Path:
    """A preset of ``configs/`` by name: in the working directory's ``configs/`` (a checkout),
    else beside the installed package (an editable install, or an image's ``/opt/col/configs``),
    so that ``col experiment --quick`` works from any folder."""
    import sys

    here = Path("configs") / name
    candidates = [here, Path(__file__).resolve().parent.parent / "configs" / name, Path(sys.prefix) / "configs" / name]
    found = next((c for c in candidates if c.is_file()), None)
    if found is None:
        raise ConfigError(f"the preset {here} is neither in this folder nor beside the installed package "
                          f"({', '.join(str(c.parent) for c in candidates[1:])}); run in the project's folder "
                          "or pass --config FILE")
    return found


def _verify(results_dir: Path, trials: int, seed: int | None, keys: list[str], keep: Path | None = None) -> None:
    """``col experiment --verify``: exit 1 when a rerun trial writes another line, saying what
    in the numeric environment differs from the one the results were made in. ``keep``: the
    reruns' folders stay there (a new or empty folder), else they go with a temporary one."""
    import contextlib
    import tempfile

    from companion.experiment.verify import environment_differences, verify

    try:
        if keep is not None and keep.exists() and (not keep.is_dir() or any(keep.iterdir())):
            raise ConfigError(f"--keep {keep}: give a new or empty folder (the reruns' folders go there)")
        with (contextlib.nullcontext(str(keep)) if keep is not None
              else tempfile.TemporaryDirectory(prefix="col-verify-")) as work:
            Path(work).mkdir(parents=True, exist_ok=True)
            checks = verify(results_dir, trials, Path(work), seed, keys)
    except ColError as exc:
        raise _fail(exc) from None
    except KeyboardInterrupt:
        raise typer.Exit(130) from None
    for check in checks:
        typer.echo(f"{check.key}: " + ("identical" if check.identical else f"DIFFERS {check.differences()}"))
    same = sum(c.identical for c in checks)
    environment = environment_differences(results_dir)
    if same != len(checks):
        typer.echo("numeric environment: " + ("; ".join(environment) if environment else
                   "the same as the results' (the difference is in the code or the data)"))
    typer.echo(json.dumps({"verified": len(checks), "identical": same, "trials": [c.key for c in checks],
                           "environment_differences": environment}))
    if same != len(checks):
        raise typer.Exit(1)


@app.command()
def ppo(
    actions: Annotated[int, typer.Option("--actions", min=2, max=4, help="2: pitch, roll (constant descent); 3: + throttle; 4: + yaw")] = 2,
    episodes: Annotated[int, typer.Option(min=1, help="training episodes (the paper: 1000)")] = 1000,
    eval_episodes: Annotated[int, typer.Option("--eval-episodes", min=1, help="held-out starts the final model flies (seeds 100000 + i, as col eval)")] = 100,
    out: Annotated[Path | None, typer.Option("--out", help="folder for model.zip, train_episodes.jsonl, results.json (default: runs/<time>-ppo<actions>); run again on it to continue an interrupted run")] = None,
    seed: Annotated[int, typer.Option(help="PPO's seed; training episode i starts from seed + i")] = 0,
    n_steps: Annotated[int, typer.Option("--n-steps", min=2, help="PPO rollout length in steps (per env)")] = 2048,
    log_std_init: Annotated[float, typer.Option("--log-std-init", help="initial log standard deviation of the policy (stable-baselines3: 0)")] = 0.0,
    ent_coef: Annotated[float, typer.Option("--ent-coef", min=0.0, help="entropy bonus (stable-baselines3: 0)")] = 0.0,
    normalize_advantage: Annotated[bool, typer.Option("--normalize-advantage/--no-normalize-advantage", help="normalise advantages per minibatch (stable-baselines3: on)")] = True,
    envs: Annotated[int, typer.Option("--envs", min=1, help="envs stepped at once (more than 1: worker processes)")] = 1,
    workers: Annotated[int | None, typer.Option("--workers", min=1, help="worker processes for the --envs envs, each stepping a group of them (default: one per env; the same episodes either way, fewer hand-overs with fewer workers)")] = None,
    mavlink: Annotated[bool, typer.Option("--mavlink", help="fly the SITL over MAVLink sockets instead of in-process (the same episodes, slower)")] = False,
    batched: Annotated[bool, typer.Option("--batched", help="train in the batched, session-free env: the same episodes, faster (--workers: processes, default 1)")] = False,
    random: Annotated[bool, typer.Option("--random", help="no training: uniformly random actions on the training starts; writes random.json")] = False,
    eval_checkpoint: Annotated[bool, typer.Option("--eval-checkpoint", help="no training: fly the latest checkpoint of the unfinished run in --out on the held-out starts; writes checkpoint_eval.json")] = False,
    config: ConfigOpt = None,
    verbose: VerboseOpt = False,
) -> None:
    """The paper's PPO baseline: sparse success reward, trained in the lockstep SITL, then evaluated."""
    _setup(verbose)
    from companion.app import default_run_dir
    from companion.rl.ppo import PpoSettings, evaluate_checkpoint, random_policy, run_ppo, summarise

    try:
        cfg = _load(config)
        folder = out or default_run_dir(cfg, f"ppo{actions}")
        if eval_checkpoint:
            if out is None:
                raise ConfigError("--eval-checkpoint needs --out: the run folder whose checkpoint to fly")
            typer.echo(json.dumps(evaluate_checkpoint(folder, cfg, config, eval_episodes)))
            return
        if random:
            with _episode_bar(episodes, f"random {actions} actions") as bar:
                runs = random_policy(actions, episodes, cfg, config, seed, lambda r: bar.update(1))
            report = {"action_dims": actions, "seed0": seed, **summarise(runs)}
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "random.json").write_text(json.dumps({"summary": report, "episodes": runs}, indent=1) + "\n")
            typer.echo(json.dumps(report))
            return
        settings = PpoSettings(action_dims=actions, episodes=episodes, eval_episodes=eval_episodes, seed=seed, n_steps=n_steps,
                               log_std_init=log_std_init, ent_coef=ent_coef, normalize_advantage=normalize_advantage,
                               n_envs=envs, inprocess=not mavlink)
        with _episode_bar(episodes, f"ppo {actions} actions", _episodes_logged(folder)) as bar:
            results = run_ppo(settings, folder, cfg, config, lambda r: bar.update(1), workers=workers, batched=batched)
    except ColError as exc:
        raise _fail(exc) from None
    ev = results["eval"]
    typer.echo(f"trained {results['train']['episodes']} episodes in {results['train']['wall_s']:.0f} s; final policy "
               f"{ev['successes']}/{ev['episodes']} = {ev['success_rate']:.0%} (95% CI {ev['ci95'][0]:.0%}-{ev['ci95'][1]:.0%})")
    typer.echo(json.dumps(ev))


@app.command()
def finetune(
    checkpoint: Annotated[Path, typer.Argument(help="a CoL checkpoint (RUN/checkpoints/episode_NNN.npz of col fly or col experiment)")],
    episodes: Annotated[int, typer.Option(min=1, help="PPO training episodes")] = 50,
    eval_episodes: Annotated[int, typer.Option("--eval-episodes", min=1, help="held-out starts flown before and after (seeds 100000 + i, as col eval)")] = 100,
    dataset: Annotated[Path | None, typer.Option("--dataset", help="the person's dataset for the behaviour-cloning term (default: human.csv of the checkpoint's run folder)")] = None,
    bc_weight: Annotated[float, typer.Option("--bc-weight", min=0.0, help="weight of the behaviour-cloning term at the start (0: the reward alone)")] = 1.0,
    bc_half_life: Annotated[float, typer.Option("--bc-half-life", min=0.001, help="PPO updates after which the term's weight has halved")] = 10.0,
    log_std_init: Annotated[float, typer.Option("--log-std-init", help="initial log standard deviation of the actions around the checkpoint's")] = -1.5,
    learning_rate: Annotated[float, typer.Option("--lr", min=1e-9, max=0.5, help="Adam's learning rate for actor and critic")] = 1e-4,
    n_steps: Annotated[int, typer.Option("--n-steps", min=2, help="PPO rollout length in steps")] = 512,
    seed: Annotated[int, typer.Option(help="PPO's seed; training episode i starts from seed + i")] = 0,
    out: Annotated[Path | None, typer.Option("--out", help="folder for results.json, finetuned.npz, model.zip (default: runs/<time>-finetune); run again on it to continue")] = None,
    config: ConfigOpt = None,
    verbose: VerboseOpt = False,
) -> None:
    """RL after CoL: PPO fine-tuning of a human-trained policy (4 actions, sparse success reward plus a
    decaying behaviour-cloning term), evaluated on the held-out starts before and after."""
    _setup(verbose)
    from companion.app import default_run_dir
    from companion.rl.finetune import FinetuneSettings, run_finetune

    try:
        cfg = _load(config)
        settings = FinetuneSettings(episodes=episodes, eval_episodes=eval_episodes, seed=seed, n_steps=n_steps,
                                    learning_rate=learning_rate, log_std_init=log_std_init, bc_weight=bc_weight,
                                    bc_half_life=bc_half_life)
        folder = out or default_run_dir(cfg, "finetune")
        with _episode_bar(episodes, "finetune", _episodes_logged(folder)) as bar:
            results = run_finetune(checkpoint, settings, folder, cfg, config, dataset, lambda r: bar.update(1))
    except ColError as exc:
        raise _fail(exc) from None
    before, after = results["before"], results["after"]
    typer.echo(f"before {before['successes']}/{before['episodes']} = {before['success_rate']:.0%}; after "
               f"{results['train']['episodes']} episodes of fine-tuning {after['successes']}/{after['episodes']} = "
               f"{after['success_rate']:.0%}; policy: {results['finetuned']}")
    typer.echo(json.dumps({"before": before, "after": after, "train": results["train"]}))


def _episodes_logged(folder: Path) -> int:
    """Training episodes a resumable PPO folder's checkpoint has seen (0 for a new folder)."""
    state = folder / "checkpoint.json"
    return int(json.loads(state.read_text())["episodes"]) if state.exists() else 0


if __name__ == "__main__":
    app()
