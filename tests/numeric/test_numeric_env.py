"""The numeric environment: pinned whatever the shell asks for, recorded, and compared."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from colcommon import numeric_env as ne
from companion.entry import PINNED_COMMANDS, command_of

AVX2_CPU = {"sse4_2", "avx", "avx2", "fma"}


def test_the_pin_overrides_whatever_kernel_the_shell_asked_for() -> None:
    env = ne.pinned_environ({"OPENBLAS_CORETYPE": "SkylakeX", "HOME": "/h", "OMP_NUM_THREADS": "8"})
    assert env["OPENBLAS_CORETYPE"] == "Haswell" and env["OMP_NUM_THREADS"] == "1" and env["HOME"] == "/h"
    assert ne.is_pinned(env)
    assert not ne.is_pinned({**env, "OPENBLAS_CORETYPE": "SkylakeX"})


def test_the_pin_is_not_applied_where_it_cannot_run_or_is_declined() -> None:
    assert ne.why_not_pinned({}, "x86_64", AVX2_CPU) is None
    assert "lacks avx2 fma" in (ne.why_not_pinned({}, "x86_64", {"sse4_2", "avx"}) or "")
    assert "aarch64" in (ne.why_not_pinned({}, "aarch64", set()) or "")
    assert "native" in (ne.why_not_pinned({"COL_NUMERIC": "native"}, "x86_64", AVX2_CPU) or "")


def test_cpu_flags_and_model_are_read_from_cpuinfo() -> None:
    info = "processor\t: 0\nmodel name\t: Some CPU @ 2GHz\nflags\t\t: fpu sse4_2 avx2 fma avx512f\n"
    assert ne.cpu_flags(info) == {"fpu", "sse4_2", "avx2", "fma", "avx512f"}
    assert ne.cpu_model(info) == "Some CPU @ 2GHz"


def test_differences_name_what_changed_and_nothing_else() -> None:
    a = ne.record()
    assert ne.differences(a, a) == []
    b = json.loads(json.dumps(a))
    b["blas"] = [{**lib, "architecture": "Prescott"} for lib in b["blas"]] or [{"architecture": "Prescott"}]
    b["packages"]["numpy"] = "0.0.1"
    lines = ne.differences(a, b)
    assert any(line.startswith("packages.numpy: ") and line.endswith("-> 0.0.1") for line in lines)
    assert any(line.startswith("blas.openblas ") and line.endswith("-> Prescott") for line in lines)
    # the CPU itself matters only for a run without the pin
    pinned = {**a, "profile": ne.PROFILE, "cpu_model": "A"}
    assert ne.differences(pinned, {**pinned, "cpu_model": "B"}) == []
    native = {**a, "profile": "native", "cpu_model": "A"}
    assert ne.differences(native, {**native, "cpu_model": "B"}) == ["cpu_model: A -> B"]


def test_records_append_and_a_torn_line_is_skipped(tmp_path: Path) -> None:
    ne.append_record(tmp_path, command=["col", "experiment"])
    with (tmp_path / ne.RECORDS_NAME).open("a") as f:
        f.write('{"torn": ')
    ne.append_record(tmp_path, command=["col", "experiment"], already_done=3)
    records = ne.read_records(tmp_path)
    assert [r.get("already_done") for r in records] == [None, 3]
    assert records[0]["packages"]["numpy"] and records[0]["python"]
    assert ne.read_records(tmp_path / "nowhere") == []


def test_the_commands_that_make_results_are_the_pinned_ones() -> None:
    assert command_of(["col", "-v", "experiment", "--config", "x"]) == "experiment"
    assert command_of(["col"]) is None
    assert {"experiment", "eval", "ppo", "finetune"} <= PINNED_COMMANDS
    assert "fly" not in PINNED_COMMANDS and "console" not in PINNED_COMMANDS


@pytest.mark.skipif(ne.why_not_pinned({}, os.uname().machine, ne.cpu_flags()) is not None,
                    reason="this CPU cannot run the x86-64-v3 profile")
@pytest.mark.parametrize("outside", ["SkylakeX", "Prescott", None])
def test_a_pinned_process_loads_the_same_kernels_whatever_the_shell_set(tmp_path: Path, outside: str | None) -> None:
    """The re-exec happens before numpy loads: OpenBLAS, numpy's dispatch and the thread
    counts are the profile's in the process that computes."""
    script = tmp_path / "probe.py"
    script.write_text("import json, sys\nfrom colcommon.numeric_env import ensure_pinned, record\n"
                      "ensure_pinned(sys.argv)\nprint(json.dumps(record()))\n")
    env = {k: v for k, v in os.environ.items() if k not in ne.PINNED}
    if outside is not None:
        env["OPENBLAS_CORETYPE"] = outside
    out = subprocess.run([sys.executable, str(script)], env=env, capture_output=True, text=True,
                         timeout=120, check=True, cwd=Path(__file__).resolve().parents[2])
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    assert rec["profile"] == ne.PROFILE
    openblas = [lib for lib in rec["blas"] if lib["internal_api"] == "openblas"]
    assert openblas and all(lib["architecture"] == "Haswell" and lib["num_threads"] == 1 for lib in openblas)
    assert "X86_V4" not in rec["numpy_dispatch"] and "AVX512_ICL" not in rec["numpy_dispatch"]


def test_a_record_says_how_to_run_again_as_it_ran() -> None:
    pinned = {"profile": ne.PROFILE, "blas": [{"internal_api": "openblas", "architecture": "Haswell"}]}
    assert ne.environ_of_record(pinned) == ne.PINNED
    native = {"profile": "native", "variables": {"OMP_NUM_THREADS": None, "OPENBLAS_CORETYPE": None},
              "blas": [{"internal_api": "openblas", "architecture": "SkylakeX"}]}
    wanted = ne.environ_of_record(native)
    assert wanted == {"OPENBLAS_CORETYPE": "SkylakeX", "COL_NUMERIC": "native"}
    assert ne.can_run_environ(wanted, "x86_64", AVX2_CPU | {"avx512f", "avx512vl"})
    assert not ne.can_run_environ(wanted, "x86_64", AVX2_CPU)  # SkylakeX kernels need AVX-512
    assert not ne.can_run_environ(ne.PINNED, "aarch64", set())
    assert ne.environ_of_record({"profile": "something else"}) is None


def test_verify_names_its_folder_either_way() -> None:
    from companion.entry import verified_folder

    assert verified_folder(["col", "experiment", "--verify", "results/x", "--trials", "1"]) == Path("results/x")
    assert verified_folder(["col", "experiment", "--verify=results/y"]) == Path("results/y")
    assert verified_folder(["col", "experiment", "--config", "c.toml"]) is None


def test_the_same_kernels_in_another_order_or_asked_for_explicitly_are_no_difference() -> None:
    lib = {"user_api": "blas", "internal_api": "openblas", "version": "0.3.31", "num_threads": 2}
    omp = {"user_api": "openmp", "internal_api": "openmp", "version": None, "num_threads": 2}
    auto = {"profile": "native", "blas": [{**lib, "architecture": "SkylakeX"}, omp],
            "variables": {"OPENBLAS_CORETYPE": None, "OMP_NUM_THREADS": None}}
    asked = {"profile": "native", "blas": [{**omp, "num_threads": 1}, {**lib, "architecture": "SkylakeX", "num_threads": 1},
                                           {**lib, "version": "0.3.15", "architecture": "SkylakeX"}],
             "variables": {"OPENBLAS_CORETYPE": "SkylakeX", "OMP_NUM_THREADS": "1"}}
    assert ne.differences(auto, asked) == []
    other = {**asked, "blas": [{**lib, "architecture": "Haswell"}], "variables": {"OPENBLAS_CORETYPE": "Haswell"}}
    assert ne.differences(auto, other) == ["blas.openblas 0.3.31: SkylakeX -> Haswell",
                                           "variables.OPENBLAS_CORETYPE: SkylakeX -> Haswell"]


def test_the_source_commit_of_a_checkout_and_of_an_export_inside_one(tmp_path) -> None:
    repo = tmp_path / "repo"
    repo.mkdir()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@example.com"]
    subprocess.run([*git, "init", "-q"], cwd=repo, check=True)
    (repo / "a.txt").write_text("a\n")
    subprocess.run([*git, "add", "a.txt"], cwd=repo, check=True)
    subprocess.run([*git, "commit", "-qm", "a"], cwd=repo, check=True)
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo, capture_output=True, text=True).stdout.strip()
    assert ne.source_commit(repo) == head
    (repo / "a.txt").write_text("b\n")
    assert ne.source_commit(repo) == head + "+dirty"
    export = repo / "runs" / "code"  # an exported commit inside the checkout: not the checkout's HEAD
    export.mkdir(parents=True)
    assert ne.source_commit(export) is None
    (export / "COMMIT").write_text("0123abc\n")
    assert ne.source_commit(export) == "0123abc"
