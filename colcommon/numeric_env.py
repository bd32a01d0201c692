"""The numeric environment: what decides the last bit of a float, recorded and pinned.

A trial is closed-loop: a policy's action moves the vehicle, which moves the next image, which
moves the next action. A rounding difference in the 16th digit (an FMA here, another summation
order there) grows until a landing succeeds in one run and misses in another. Which machine
code the numeric libraries run is chosen at load time from the CPU:

- numpy's OpenBLAS picks a kernel per core type (``OPENBLAS_CORETYPE``);
- numpy's own loops dispatch on SIMD features (``NPY_DISABLE_CPU_FEATURES``);
- torch's ATen kernels (``ATEN_CPU_CAPABILITY``), its MKL (``MKL_CBWR``) and oneDNN
  (``ONEDNN_MAX_CPU_ISA``) do the same;
- OpenCV dispatches its loops too (``OPENCV_CPU_DISABLE``);
- and threaded reductions depend on the thread count.

So a result is a pure function of its settings only under one such choice. The project pins
one that nearly every x86-64 machine in use runs: x86-64-v3 (AVX2 + FMA, Intel Haswell of 2013
and later, AMD Zen and later). Pinned means set in the environment *before* the libraries load,
so commands that make results re-execute themselves with it (:func:`ensure_pinned`), and every
worker and SITL process they start inherits it.

:func:`record` writes down what a run actually ran with (versions, the BLAS library and its
core type as loaded, the CPU, the variables), and :func:`differences` says, for a rerun that
did not match, which of these changed.
"""

from __future__ import annotations

import json
import os
import platform
import sys
from collections.abc import Mapping, MutableMapping
from importlib import metadata
from pathlib import Path
from typing import Any

PROFILE = "x86-64-v3"
"""The pinned profile's name, recorded with every result."""

PINNED: dict[str, str] = {
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_CBWR": "AVX2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "OPENCV_CPU_DISABLE": "AVX512-SKX",
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "COL_NUMERIC_PROFILE": PROFILE,
}
"""The environment of the x86-64-v3 profile. numpy >= 2.4 names its AVX-512 dispatch targets
``X86_V4``, ``AVX512_ICL`` and ``AVX512_SPR``; OpenCV names its one ``AVX512-SKX``."""

REQUIRED_CPU_FLAGS = ("avx2", "fma")
"""What the profile's kernels execute: a CPU without them cannot run the pin."""

OPT_OUT = "COL_NUMERIC"
"""``COL_NUMERIC=native`` runs with the CPU's own kernels (faster, not reproducible elsewhere)."""

RECORDED_VARIABLES = (*PINNED, "NPY_ENABLE_CPU_FEATURES", "PYTHONHASHSEED",
                      "CUBLAS_WORKSPACE_CONFIG", OPT_OUT)
"""Variables that change numbers, recorded as the run saw them (absent: None)."""

CPU_FLAGS_OF_INTEREST = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw",
                         "avx512dq", "avx512_vnni", "avx512_bf16", "amx_tile")
PACKAGES = ("numpy", "torch", "opencv-python-headless", "jsbsim", "pymavlink", "scipy",
            "stable-baselines3", "gymnasium", "threadpoolctl")


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``; empty where it cannot be read)."""
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo") as f:
                cpuinfo = f.read()
        except OSError:
            return set()
    for line in cpuinfo.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def cpu_model(cpuinfo: str | None = None) -> str:
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo") as f:
                cpuinfo = f.read()
        except OSError:
            return platform.processor() or "unknown"
    for line in cpuinfo.splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return platform.processor() or "unknown"


def can_run_profile(machine: str, flags: set[str]) -> bool:
    """Whether this CPU runs the pinned kernels (x86-64 with AVX2 and FMA)."""
    return machine in ("x86_64", "AMD64") and all(f in flags for f in REQUIRED_CPU_FLAGS)


def pinned_environ(environ: Mapping[str, str]) -> dict[str, str]:
    """``environ`` with the profile's variables set (whatever the shell had asked for)."""
    return {**environ, **PINNED}


def is_pinned(environ: Mapping[str, str]) -> bool:
    return all(environ.get(k) == v for k, v in PINNED.items())


def why_not_pinned(environ: Mapping[str, str], machine: str, flags: set[str]) -> str | None:
    """None if the profile should be applied here, else the reason it is not."""
    if environ.get(OPT_OUT, "").lower() == "native":
        return f"{OPT_OUT}=native: the CPU's own kernels, results will not match other machines byte for byte"
    if not can_run_profile(machine, flags):
        missing = [f for f in REQUIRED_CPU_FLAGS if f not in flags]
        return (f"this CPU ({machine}{', lacks ' + ' '.join(missing) if missing else ''}) cannot run the "
                f"{PROFILE} profile: its own kernels are used, results will not match byte for byte")
    return None


def ensure_pinned(argv: list[str], environ: MutableMapping[str, str] | None = None) -> str | None:
    """Re-execute this process with the profile's environment unless it already has it.

    Returns None when pinned (after the re-exec), or the reason the profile is not applied
    (the caller logs it). Must run before anything computes: the libraries already loaded in
    this process are replaced with the exec.
    """
    env = os.environ if environ is None else environ
    reason = why_not_pinned(env, platform.machine(), cpu_flags())
    if reason is None:
        ensure_environ(argv, PINNED, env)  # returns only when already pinned
    return reason


AVX512_CORE_TYPES = frozenset({"SkylakeX", "Cooperlake", "SapphireRapids"})
"""OpenBLAS core types whose kernels execute AVX-512."""


def environ_of_record(rec: Mapping[str, Any]) -> dict[str, str] | None:
    """The variables that reproduce a recorded environment: the profile's, or for a run made
    with the CPU's own kernels the OpenBLAS core type it loaded (and the variables it had set).
    None for a record that names neither."""
    if rec.get("profile") == PROFILE:
        return dict(PINNED)
    if rec.get("profile") != "native":
        return None
    env = {k: str(v) for k, v in (rec.get("variables") or {}).items()
           if v is not None and k not in ("COL_NUMERIC_PROFILE", OPT_OUT)}
    arch = next((lib.get("architecture") for lib in rec.get("blas") or [] if lib.get("internal_api") == "openblas"), None)
    if arch:
        env["OPENBLAS_CORETYPE"] = str(arch)
    env[OPT_OUT] = "native"
    return env


def can_run_environ(wanted: Mapping[str, str], machine: str, flags: set[str]) -> bool:
    """Whether this CPU executes the kernels ``wanted`` asks for."""
    if wanted.get(OPT_OUT) != "native":
        return can_run_profile(machine, flags)
    core = wanted.get("OPENBLAS_CORETYPE")
    if core in AVX512_CORE_TYPES:
        return "avx512f" in flags and "avx512vl" in flags
    return True


def ensure_environ(argv: list[str], wanted: Mapping[str, str], environ: MutableMapping[str, str] | None = None) -> None:
    """Re-execute with exactly ``wanted`` of the numeric variables (the others of
    :data:`PINNED` removed) unless this process already has it."""
    env = os.environ if environ is None else environ
    if all(env.get(k) == v for k, v in wanted.items()) and all(k in wanted or k not in env for k in PINNED):
        return
    new = {k: v for k, v in env.items() if k not in PINNED or k in wanted}
    os.execve(sys.executable, [sys.executable, *argv], {**new, **wanted})


def _blas() -> list[dict[str, object]]:
    """The BLAS/OpenMP libraries loaded now, as threadpoolctl reads them (core type included)."""
    try:
        import numpy  # noqa: F401  (loads numpy's OpenBLAS so that it is listed)
        from threadpoolctl import threadpool_info
    except ImportError:
        return []
    keep = ("user_api", "internal_api", "version", "architecture", "num_threads", "threading_layer")
    return [{k: lib.get(k) for k in keep} for lib in threadpool_info()]


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def _torch_capability() -> str | None:
    if "torch" not in sys.modules:  # loading torch only to ask costs seconds; a run that uses it has it
        return None
    import torch

    return str(torch.backends.cpu.get_cpu_capability())


def _numpy_dispatch() -> list[str]:
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return []
    return [name for name in __cpu_dispatch__ if __cpu_features__.get(name)]


def record(environ: Mapping[str, str] | None = None) -> dict[str, object]:
    """What this process computes with: one JSON-able dict (see the module docstring)."""
    env = os.environ if environ is None else environ
    flags = cpu_flags()
    return {
        "profile": env.get("COL_NUMERIC_PROFILE") if is_pinned(env) else "native",
        "python": platform.python_version(),
        "packages": {p: _version(p) for p in PACKAGES},
        "blas": _blas(),
        "numpy_dispatch": _numpy_dispatch(),
        "torch_cpu_capability": _torch_capability(),
        "machine": platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_flags": sorted(f for f in CPU_FLAGS_OF_INTEREST if f in flags),
        "variables": {k: env.get(k) for k in RECORDED_VARIABLES},
    }


COMPARED = ("profile", "python", "packages", "numpy_dispatch", "torch_cpu_capability", "machine")
"""What must match for a rerun to match, beside the BLAS kernels and the variables (the CPU
model and flags may differ under the pin)."""
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""Not compared: the processes that compute (the grid's workers) set one thread themselves."""


def blas_kernels(rec: Mapping[str, Any]) -> dict[str, str | None]:
    """``{"openblas 0.3.31": "SkylakeX", ...}``: each BLAS library's kernel, in any order."""
    return {f"{lib.get('internal_api')} {lib.get('version')}": lib.get("architecture")
            for lib in rec.get("blas") or [] if lib.get("user_api") == "blas"}


def effective_variables(rec: Mapping[str, Any]) -> dict[str, Any]:
    """The record's numeric variables, ``OPENBLAS_CORETYPE`` as the kernel numpy's OpenBLAS
    loaded when none was set (auto-chosen SkylakeX and asked-for SkylakeX are the same)."""
    variables = {k: v for k, v in (rec.get("variables") or {}).items() if k not in THREAD_VARIABLES}
    if variables.get("OPENBLAS_CORETYPE") is None:
        loaded = [v for k, v in blas_kernels(rec).items() if k.startswith("openblas")]
        variables["OPENBLAS_CORETYPE"] = loaded[0] if loaded else None
    return variables


def differences(recorded: Mapping[str, Any], current: Mapping[str, Any]) -> list[str]:
    """Human-readable lines, one per difference that can change numbers, e.g.
    ``blas.openblas 0.3.31: SkylakeX -> Haswell``; empty when they agree."""
    lines: list[str] = []
    for key in COMPARED:
        a, b = recorded.get(key), current.get(key)
        if key == "torch_cpu_capability" and (a is None or b is None):
            continue  # not known where torch had not been loaded when the record was made
        _diff(key, a, b, lines)
    kernels_a, kernels_b = blas_kernels(recorded), blas_kernels(current)
    for lib in sorted(kernels_a.keys() & kernels_b.keys()):  # a library loaded by one process only computes nothing the other did
        _diff(f"blas.{lib}", kernels_a[lib], kernels_b[lib], lines)
    _diff("variables", effective_variables(recorded), effective_variables(current), lines)
    if recorded.get("profile") == "native" or current.get("profile") == "native":
        for key in ("cpu_model", "cpu_flags"):  # only unpinned runs depend on the CPU itself
            _diff(key, recorded.get(key), current.get(key), lines)
    return lines


def _diff(path: str, a: object, b: object, out: list[str]) -> None:
    if isinstance(a, Mapping) and isinstance(b, Mapping):
        for k in sorted(set(a) | set(b)):
            _diff(f"{path}.{k}", a.get(k), b.get(k), out)
    elif isinstance(a, list) and isinstance(b, list) and a and isinstance(a[0], Mapping) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _diff(f"{path}[{i}]", x, y, out)
    elif a != b:
        out.append(f"{path}: {a} -> {b}")


RECORDS_NAME = "environment.jsonl"
"""One line per start of a run or a results folder's grid (a resumed grid adds one)."""


def source_commit(root: Path | None = None) -> str | None:
    """The code's git commit (``+dirty`` with uncommitted changes), or None outside a checkout.

    A clean export of a commit (``git archive``, e.g. results/learner-ablation/run.py's) is no
    checkout: its commit is the one its ``COMMIT`` file names, never that of a checkout it happens
    to sit inside."""
    import subprocess

    where = (root or Path(__file__).resolve().parent.parent).resolve()
    marker = where / "COMMIT"
    try:
        top = subprocess.run(["git", "rev-parse", "--show-toplevel"], cwd=where, capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
        if Path(top).resolve() != where:
            return marker.read_text().strip() if marker.is_file() else None
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=where,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return marker.read_text().strip() if marker.is_file() else None
    return head + ("+dirty" if dirty else "")


def append_record(folder: Path, **context: object) -> dict[str, object]:
    """Add this process's :func:`record` (with ``context``: the command, the start) and the
    code's commit to ``folder``."""
    line = {**context, "commit": source_commit(), **record()}
    path = folder / RECORDS_NAME
    torn = path.exists() and path.stat().st_size > 0 and path.read_bytes()[-1:] != b"\n"
    with path.open("a") as f:  # a killed writer's torn line stays a line of its own
        f.write(("\n" if torn else "") + json.dumps(line, sort_keys=True) + "\n")
    return line


def read_records(folder: Path) -> list[dict[str, Any]]:
    """The records of ``folder``, oldest first (none: an empty list, e.g. results made before
    records were kept). A torn last line (a killed process) is skipped, not fatal."""
    path = folder / RECORDS_NAME
    if not path.exists():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


if __name__ == "__main__":  # `python -m colcommon.numeric_env`: this process's record, as JSON
    print(json.dumps(record(), indent=1, sort_keys=True))
