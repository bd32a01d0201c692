"""The Ray backend: a grid on Ray writes what the process pool writes.

The e2e tests start (and stop) their own local Ray instance, ``ray.init(num_cpus=2)``, or a
``ray start --head`` cluster on loopback: 5-10 s each on the 2-core development machine, the
real 2-trial grid 15-45 s. CI installs the ``cluster`` extra, so they run there; the import
guard only spares an environment without Ray.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.experiment import ray_backend
from companion.experiment.grid import (
    ExperimentConfig,
    ExperimentSetup,
    TrainingRun,
    expand,
    load_experiment,
)
from companion.experiment.ray_backend import ray_instance
from companion.experiment.results import TrialResult
from companion.experiment.runner import run_grid
from tests.conftest import ONE_AFTER_ANOTHER

# one worker runs these in turn: each checks that no Ray process or session folder is left,
# which another worker's Ray instance (started at the same time) would break. The same worker runs
# the real-autopilot and browser tests before these (tests/conftest.py, ONE_AFTER_ANOTHER): a local Ray instance has a fixed
# 30 s of the wall clock for its raylet to register, and beside PX4 SIH and ArduCopter at 4-5x (at
# the real-time tests' higher priority) it missed that twice in a CI run at load 18
# (bench/results/ci-fresh-2026-12-07-36-failed.txt); nor does a Ray grid's CPU-heavy burst then
# starve real PX4's offboard stream (two bursts at once, a load of 13, once did).
pytestmark = [pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(900)]  # upper bound at load ~10
REPO = Path(__file__).resolve().parents[2]
DRIVER_PID = os.getpid()
"""This process: the driver of the Ray instances the tests start (captured by value by Ray)."""

def _descendants(pid: int) -> list[int]:
    children, found, todo = ray_backend.process_children(), [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if _alive(child):
                found.append(child)
            todo.append(child)
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _session_members(sid: int) -> list[int]:
    pids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            pids.append(int(stat.parent.name))
    return pids


def _address(hex_address: str) -> str:
    """A /proc/net address ("0100007F:1F90") as "127.0.0.1:8080" (v6: "[::1]:8080")."""
    ip_hex, port_hex = hex_address.split(":")
    raw = bytes.fromhex(ip_hex)
    ip = ipaddress.ip_address(b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4)))
    return f"{ip}:{int(port_hex, 16)}" if ip.version == 4 else f"[{ip}]:{int(port_hex, 16)}"


def _is_loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address.rsplit(":", 1)[0].strip("[]"))
    mapped = getattr(ip, "ipv4_mapped", None)
    return ip.is_loopback or (mapped is not None and mapped.is_loopback)


def _ray_sockets() -> list[str]:
    """Where the Ray instance's processes (this driver's descendants) listen: TCP listening
    sockets and bound UDP sockets, as "tcp 127.0.0.1:port"."""
    inodes = set()
    for pid in _descendants(DRIVER_PID):
        try:
            links = [os.readlink(fd) for fd in Path(f"/proc/{pid}/fd").iterdir()]
        except OSError:
            continue
        inodes |= {link[8:-1] for link in links if link.startswith("socket:[")}
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        for row in Path(f"/proc/net/{proto}").read_text().splitlines()[1:]:
            fields = row.split()
            listening = fields[3] == "0A" if proto.startswith("tcp") else True
            if listening and fields[9] in inodes:
                found.append(f"{proto} {_address(fields[1])}")
    return found


def fake_run(setup: ExperimentSetup, run: TrainingRun, out_dir: Path) -> list[TrialResult]:
    """Stands in for run_training in a worker: marks the call (with where it ran); P2's run
    raises its first time, P3's kills its worker its first time (as the OOM killer would); in a
    Ray worker it also notes where the Ray instance listens."""
    ray = sys.modules.get("ray")
    where = "ray" if ray is not None and ray.is_initialized() else "pool"
    (out_dir / "calls").mkdir(exist_ok=True)
    mark = out_dir / "calls" / f"{run.key}.{where}"
    with mark.open("a") as fh:
        fh.write("x")
    if where == "ray":
        (out_dir / "sockets.json").write_text(json.dumps(_ray_sockets()))
    first = len(mark.read_text()) == 1
    if run.participant == "P2" and first:
        raise RuntimeError("the SITL did not start")
    if run.participant == "P3" and first:
        os.kill(os.getpid(), signal.SIGKILL)
    return [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="ok", eval_runs=4,
                        eval_successes=t.interactions, human_samples=100 * t.interactions,
                        interventions=run.episodes, train_wall_s=0.1 * t.interactions, eval_wall_s=0.5,
                        final_checkpoint=f"trials/{run.key}/train/checkpoints/episode_{t.interactions - 1:03d}.npz")
            for t in run.trials]


def calls(out_dir: Path) -> dict[str, int]:
    return {p.name: len(p.read_text()) for p in (out_dir / "calls").iterdir()}


def lines(out_dir: Path) -> list[str]:
    """results.jsonl's lines, sorted: the file is in completion order, which may differ."""
    return sorted((out_dir / "results.jsonl").read_text().splitlines())


def _leftovers() -> list[int]:
    """This process's descendants but the process pool's resource tracker (it lives as long as we do)."""
    return [pid for pid in _descendants(DRIVER_PID)
            if b"multiprocessing.resource_tracker" not in Path(f"/proc/{pid}/cmdline").read_bytes()]


@pytest.fixture
def ray_cleanly() -> Iterator[None]:
    """Ray, with this module's functions sent to workers by value; afterwards no Ray process
    or session folder of the test may be left."""
    ray = pytest.importorskip("ray")  # only a guard: CI installs the cluster extra
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    before = set(Path("/tmp").glob("colray-*"))
    yield
    assert not ray.is_initialized()
    deadline = time.monotonic() + 15
    while (left := _leftovers()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert left == [], [Path(f"/proc/{p}/cmdline").read_bytes()[:80] for p in left]
    assert set(Path("/tmp").glob("colray-*")) == before


@pytest.mark.e2e
def test_a_grid_on_local_ray_writes_the_process_pools_lines_and_resumes(tmp_path: Path, ray_cleanly: None) -> None:
    """4 trials in 2 runs (Demo@1 and Demo@2 of P1 share one, P2's raises once), on both
    backends: the same lines, and on resume only the failed run runs again. A run whose worker
    dies is an error result too. One local instance serves every grid here (run_grid uses
    an initialised Ray as it is)."""
    setup = ExperimentSetup(ExperimentConfig(participants=("P1", "P2"), conditions=("demo",), interactions=(1, 2),
                                             eval_runs=4), CompanionConfig())
    pool, on_ray = tmp_path / "pool", tmp_path / "ray"
    first = run_grid(setup, pool, workers=2, progress=False, run_fn=fake_run)
    assert [r.trial.key for r in first] == ["P1-demo-02-s0", "P1-demo-01-s0"]
    pool_first = lines(pool)
    resumed = run_grid(setup, pool, workers=2, progress=False, run_fn=fake_run)
    pool_lines = lines(pool)
    with ray_instance(2, None) as ray:
        assert run_grid(setup, on_ray, workers=2, progress=False, run_fn=fake_run, backend="ray") == first
        assert lines(on_ray) == pool_first and len(pool_first) == 4
        assert sum('"status": "error"' in line for line in lines(on_ray)) == 2
        assert calls(on_ray) == {"P1-demo-02-s0.ray": 1, "P2-demo-02-s0.ray": 1}  # in Ray workers
        sockets = json.loads((on_ray / "sockets.json").read_text())
        assert any(s.startswith("tcp") for s in sockets)
        assert [s for s in sockets if not _is_loopback(s.split()[1])] == []  # loopback only
        assert len((on_ray / "timings.jsonl").read_text().splitlines()) == 4

        assert run_grid(setup, on_ray, workers=2, progress=False, run_fn=fake_run, backend="ray") == resumed
        assert [r.trial.key for r in resumed] == [t.key for t in expand(setup.exp)]
        assert lines(on_ray) == pool_lines and len(pool_lines) == 6
        assert calls(on_ray) == {"P1-demo-02-s0.ray": 1, "P2-demo-02-s0.ray": 2}  # only the failed run
        before = (on_ray / "results.jsonl").read_bytes()
        again = run_grid(setup, on_ray, workers=2, progress=False, run_fn=fake_run, backend="ray")
        assert [r.to_json_line() for r in again] == [r.to_json_line() for r in resumed]
        assert (on_ray / "results.jsonl").read_bytes() == before  # all done: nothing ran
        assert calls(on_ray) == {"P1-demo-02-s0.ray": 1, "P2-demo-02-s0.ray": 2}

        crash = dataclasses.replace(setup, exp=ExperimentConfig(participants=("P3",), conditions=("col",),
                                                                interactions=(2,), eval_runs=4))
        assert run_grid(crash, tmp_path / "crash", workers=2, progress=False, run_fn=fake_run, backend="ray") == []
        (line,) = (tmp_path / "crash" / "results.jsonl").read_text().splitlines()
        assert json.loads(line)["status"] == "error" and "WorkerCrashedError" in json.loads(line)["error"]
        (ok,) = run_grid(crash, tmp_path / "crash", workers=2, progress=False, run_fn=fake_run, backend="ray")
        assert ok.status == "ok" and calls(tmp_path / "crash") == {"P3-col-02-s0.ray": 2}
        assert ray.is_initialized()  # left running for its owner


def test_without_ray_the_backend_says_how_to_install_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ray_backend, "ray_installed", lambda: False)
    setup = ExperimentSetup(ExperimentConfig(participants=("P1",), conditions=("col",), interactions=(1,)),
                            CompanionConfig())
    with pytest.raises(ConfigError, match=r"pip install '\.\[cluster\]'"):
        run_grid(setup, tmp_path, workers=1, progress=False, run_fn=fake_run, backend="ray")
    assert not (tmp_path / "results.jsonl").exists()


@pytest.mark.e2e
def test_a_real_two_trial_grid_on_local_ray_matches_the_process_pool_byte_for_byte(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ray_cleanly: None) -> None:
    """Demo@1 and CoL@1 of P1 on the lockstep SITL, 2 evaluation runs each, with the quick
    experiment file's settings: the process pool's results.jsonl lines and datasets, exactly.
    The file is named relative to the repository, as `col experiment` names it: Ray workers
    run elsewhere and read the results folder's copy."""
    monkeypatch.chdir(REPO)
    setup = load_experiment(Path("configs/experiment_quick.toml"))
    setup = dataclasses.replace(setup, exp=ExperimentConfig(
        participants=("P1",), conditions=("demo", "col"), interactions=(1,), eval_runs=2))
    pool, ray = tmp_path / "pool", tmp_path / "ray"
    by_pool = run_grid(setup, pool, workers=2, progress=False)
    assert [(r.trial.key, r.status) for r in by_pool] == [("P1-demo-01-s0", "ok"), ("P1-col-01-s0", "ok")]
    by_ray = run_grid(setup, ray, workers=2, progress=False, backend="ray")
    assert lines(ray) == lines(pool) and len(lines(ray)) == 2
    assert [dataclasses.replace(r, train_wall_s=0, eval_wall_s=0) for r in by_ray] == \
        [dataclasses.replace(r, train_wall_s=0, eval_wall_s=0) for r in by_pool]
    for key in ("P1-demo-01-s0", "P1-col-01-s0"):
        csv = f"trials/{key}/train/human.csv"
        assert (ray / csv).read_bytes() == (pool / csv).read_bytes()


DRIVER = """
import subprocess, sys
from pathlib import Path

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.experiment import ray_backend
from companion.experiment.grid import ExperimentConfig, ExperimentSetup
from companion.experiment.ray_backend import ray_instance
from companion.experiment.results import TrialResult
from companion.experiment.runner import run_grid


def slow_run(setup, run, out_dir):
    if run.participant != "P1":  # blocked in a subprocess wait, as a trial waits on its SITL
        child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
        (out_dir / f"child-{child.pid}").touch()
        child.wait()
    return [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="ok", eval_runs=1, eval_successes=1)
            for t in run.trials]


setup = ExperimentSetup(ExperimentConfig(participants=("P1", "P2", "P3"), conditions=("col",), interactions=(1,),
                                         eval_runs=1), CompanionConfig())
try:
    run_grid(setup, Path(sys.argv[1]), workers=2, progress=False, run_fn=slow_run, backend="ray")
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
print("not interrupted", flush=True)
"""


@pytest.mark.e2e
def test_ctrl_c_cancels_running_tasks_kills_their_children_and_keeps_finished_results(
        tmp_path: Path, ray_cleanly: None) -> None:
    """P1's run finishes, P2's and P3's block in a subprocess wait; SIGINT to the driver alone
    (as on a cluster, where the workers get no Ctrl-C): exit 130, only P1's line recorded,
    the blocked tasks' children gone, the local instance and its folder gone."""
    script, out, log = tmp_path / "driver.py", tmp_path / "out", tmp_path / "driver.log"
    script.write_text(textwrap.dedent(DRIVER))
    out.mkdir()
    with log.open("w") as fh:  # a session of its own: whatever it starts can be found (and killed) by it
        driver = subprocess.Popen([sys.executable, str(script), str(out)], cwd=tmp_path, start_new_session=True,
                                  stdout=fh, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and driver.poll() is None:
            done = (out / "results.jsonl").exists() and (out / "results.jsonl").read_text()
            if done and len(list(out.glob("child-*"))) == 2:
                break
            time.sleep(0.1)
        else:
            pytest.fail(f"the grid did not get going:\n{log.read_text()}")
        children = [int(p.name.split("-")[1]) for p in out.glob("child-*")]
        t0 = time.monotonic()
        driver.send_signal(signal.SIGINT)
        assert driver.wait(timeout=60) == 130, log.read_text()
        print(f"SIGINT to driver exit: {time.monotonic() - t0:.1f} s")
        keys = [json.loads(line)["trial"]["key"] for line in (out / "results.jsonl").read_text().splitlines()]
        assert keys == ["P1-col-01-s0"]
        deadline = time.monotonic() + 15
        while (left := _session_members(driver.pid)) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert left == [], [Path(f"/proc/{p}/cmdline").read_bytes()[:80] for p in left]
        assert not any(_alive(pid) for pid in children)
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
        for pid in _session_members(driver.pid):  # what the driver started and left behind
            os.kill(pid, signal.SIGKILL)


CLUSTER_DRIVER = """
import json, os, sys
from pathlib import Path

from companion.experiment.grid import ExperimentConfig, load_experiment
from companion.experiment.results import TrialResult
from companion.experiment.runner import run_grid


def where_run(setup, run, out_dir):
    (out_dir / f"ran-{run.key}.json").write_text(json.dumps(
        {"cwd": os.getcwd(), "config": str(setup.config_path), "readable": setup.config_path.is_file()}))
    return [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="ok", eval_runs=1, eval_successes=1)
            for t in run.trials]


setup = load_experiment(Path("configs/experiment_quick.toml"))  # relative, as `col experiment` names it
setup = setup.__class__(ExperimentConfig(participants=("P1", "P2"), conditions=("col",), interactions=(1,)),
                        setup.companion, setup.config_path, setup.sitl_tables)
results = run_grid(setup, Path(sys.argv[2]), workers=2, progress=False, run_fn=where_run, backend="ray",
                   address=sys.argv[1])
print(json.dumps([r.status for r in results]), flush=True)
"""


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.e2e
def test_a_grid_on_a_ray_start_cluster_with_token_authentication(tmp_path: Path, ray_cleanly: None) -> None:
    """`ray start --head` (Ray's token authentication on, loopback) and a driver that connects
    with --address and the token: the runs execute in the cluster's workers (in the directory
    of `ray start`), which read the results folder's copy of the experiment file."""
    import secrets
    import tempfile

    port, token = _free_port(), secrets.token_hex(16)
    temp_dir = tempfile.mkdtemp(prefix="colray-", dir="/tmp")
    loopback = dict(os.environ, RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0", RAY_USAGE_STATS_ENABLED="0")
    with_token = dict(loopback, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token)
    ray_cli = Path(sys.executable).with_name("ray")
    with (tmp_path / "head.log").open("w") as log:  # a session of its own: every process of the cluster
        head = subprocess.Popen(
            [str(ray_cli), "start", "--head", "--port", str(port), "--num-cpus", "2", "--include-dashboard=false",
             "--object-store-memory", str(75 * 2**20), "--temp-dir", temp_dir, "--block"],
            cwd=temp_dir, env=with_token, start_new_session=True, stdout=log, stderr=subprocess.STDOUT)
    try:
        script, out = tmp_path / "driver.py", tmp_path / "out"
        script.write_text(textwrap.dedent(CLUSTER_DRIVER))
        driver = subprocess.run([sys.executable, str(script), f"127.0.0.1:{port}", str(out)], cwd=REPO,
                                env=with_token, capture_output=True, text=True, timeout=120)
        assert driver.returncode == 0, driver.stderr[-3000:] + (tmp_path / "head.log").read_text()[-2000:]
        assert json.loads(driver.stdout.splitlines()[-1]) == ["ok", "ok"]
        for key in ("P1-col-01-s0", "P2-col-01-s0"):
            ran = json.loads((out / f"ran-{key}.json").read_text())
            assert ran == {"cwd": temp_dir, "config": str(out / "config.toml"), "readable": True}
        assert len((out / "results.jsonl").read_text().splitlines()) == 2
    finally:
        head.terminate()  # `ray start --block` stops the node's processes on SIGTERM
        try:
            head.wait(timeout=30)
        finally:
            deadline = time.monotonic() + 15
            while (left := _session_members(head.pid)) and time.monotonic() < deadline:
                time.sleep(0.2)
            for pid in left:
                os.kill(pid, signal.SIGKILL)
            shutil.rmtree(temp_dir, ignore_errors=True)
    assert left == []


class _SlowStartRay:
    """A stand-in for the ``ray`` module whose first ``init`` times out as Ray's does under load."""

    def __init__(self, failures: int, message: str = "The current node timed out during startup.") -> None:
        self.failures, self.message, self.temp_dirs, self.shutdowns = failures, message, [], 0

    def init(self, **kwargs: object) -> None:
        self.temp_dirs.append(kwargs.get("_temp_dir"))
        if len(self.temp_dirs) <= self.failures:
            raise Exception(self.message)

    def shutdown(self) -> None:
        self.shutdowns += 1


def test_a_local_start_that_timed_out_is_killed_and_started_once_more(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    killed: list[int] = []
    monkeypatch.setattr(ray_backend, "_kill_ray_descendants", lambda: killed.append(1))
    first = tmp_path / "colray-a"
    first.mkdir()
    ray = _SlowStartRay(failures=1)
    kwargs: dict[str, object] = {"_temp_dir": str(first)}
    ray_backend._init(ray, kwargs, local=True)
    assert len(ray.temp_dirs) == 2 and ray.temp_dirs[1] != str(first) and killed == [1]
    assert not first.exists() and Path(ray.temp_dirs[1]).is_dir()  # the failed start's session folder is gone
    shutil.rmtree(ray.temp_dirs[1])

    twice = _SlowStartRay(failures=2)  # a second timeout is the caller's error, and nothing is left running
    with pytest.raises(Exception, match="timed out"):
        ray_backend._init(twice, {"_temp_dir": str(tmp_path / "colray-b")}, local=True)
    assert len(twice.temp_dirs) == ray_backend.LOCAL_START_ATTEMPTS and killed == [1, 1, 1]
    for leftover in twice.temp_dirs[1:]:
        shutil.rmtree(leftover, ignore_errors=True)

    other = _SlowStartRay(failures=1, message="bad argument")  # not a slow start: no second try
    with pytest.raises(Exception, match="bad argument"):
        ray_backend._init(other, {"_temp_dir": str(tmp_path / "colray-c")}, local=True)
    assert len(other.temp_dirs) == 1
    cluster = _SlowStartRay(failures=1)  # a cluster is not started here: nothing to kill or retry
    with pytest.raises(Exception, match="timed out"):
        ray_backend._init(cluster, {"address": "127.0.0.1:6379"}, local=False)
    assert cluster.temp_dirs == [None] and killed == [1, 1, 1, 1]  # the "bad argument" start was killed too


def test_ray_descendants_finds_only_this_process_s_ray_children(tmp_path: Path) -> None:
    fake_ray = tmp_path / "site-packages" / "ray" / "raylet.py"
    fake_ray.parent.mkdir(parents=True)
    fake_ray.write_text("import time\ntime.sleep(60)\n")
    other = tmp_path / "other.py"
    other.write_text("import time\ntime.sleep(60)\n")
    rayish = subprocess.Popen([sys.executable, str(fake_ray)])
    plain = subprocess.Popen([sys.executable, str(other)])
    try:
        found = ray_backend.ray_descendants(os.getpid())
        assert rayish.pid in found and plain.pid not in found
    finally:
        rayish.kill(), plain.kill()
        rayish.wait(), plain.wait()
