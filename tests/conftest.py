"""Shared fixtures: the motion capture folder and its manifest.

Tests that need ../shared/mocap skip with a reason when it is absent, unless
JAXSTYLE_REQUIRE_MOCAP=1 (set by .ci/run), where a missing folder fails them instead.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import pytest

from jaxstyle.data.locate import ENV_VAR, default_mocap_dir

# XLA's backend optimisations off for the test run (before JAX starts in this process; the
# xdist workers import this file first): most of the tests' time is compiling small programs once,
# and without the LLVM optimisations that compile takes far less (tests/test_fewshot.py and
# test_equations.py: 69 s -> 42 s on the 2-core machine) while every result is computed the same
# way up to float rounding. Benchmarks and the command line keep XLA's default.
# JAXSTYLE_TEST_XLA_DEFAULT=1 keeps the default optimisation in the tests too.
_FAST_COMPILE = "--xla_backend_optimization_level=0"
if os.environ.get("JAXSTYLE_TEST_XLA_DEFAULT") != "1" and "xla_backend_optimization_level" not in os.environ.get(
        "XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + _FAST_COMPILE).strip()

# Under pytest-xdist every worker is one of -n processes sharing the machine's cores: each runs
# XLA's CPU kernels and numpy on one thread, so the workers (and the commands they start, which
# inherit this environment) do not oversubscribe the cores.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

# The command line's persistent compilation cache (jaxstyle.cli.common.use_xla_cache) stays off in
# the tests; tests of the cache set the variable themselves.
os.environ.setdefault("JAXSTYLE_XLA_CACHE", "off")

# One JAX compilation cache for the whole test run: a fresh folder made by the first pytest process
# (inherited by the xdist workers and every command the tests start, through the environment) and
# removed when that process ends. A program is compiled the first time the run needs it; the same
# program, compiled again in another worker or a command the tests start, is loaded instead (JAX
# keys the cache on the program, the compile options, the XLA flags and the versions, so a hit is
# the same executable). JAX's own thresholds apply (only programs that took at least 1 s to compile
# are kept). JAXSTYLE_TEST_COMPILE_CACHE=off compiles everything.
_RUN_CACHE = "JAXSTYLE_TEST_COMPILE_CACHE"
if _RUN_CACHE not in os.environ:
    import atexit
    import shutil
    import tempfile

    os.environ[_RUN_CACHE] = tempfile.mkdtemp(prefix="jaxstyle-test-xla-")
    atexit.register(shutil.rmtree, os.environ[_RUN_CACHE], True)
if os.environ[_RUN_CACHE] != "off":
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.environ[_RUN_CACHE])  # read by JAX when it starts


def _mocap_or_skip() -> Path:
    path = default_mocap_dir()
    if path.is_dir() and any(path.rglob("*.bvh")):
        return path
    reason = f"motion capture not found at {path} (set {ENV_VAR})"
    if os.environ.get("JAXSTYLE_REQUIRE_MOCAP") == "1":
        pytest.fail(reason + "; JAXSTYLE_REQUIRE_MOCAP=1 makes this an error")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def mocap() -> Path:
    return _mocap_or_skip()


@pytest.fixture(scope="session")
def manifest(mocap) -> dict[str, dict]:
    with open(mocap / "MANIFEST.tsv", newline="") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    return {r["file"]: r for r in rows if r["file"].endswith(".bvh")}


def all_bvh(mocap: Path) -> list[Path]:
    return sorted(mocap.rglob("*.bvh"))
