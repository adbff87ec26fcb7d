"""Multi-process JAX (``--distributed``) on this machine: two local processes, one CPU device each,
joined by ``jax.distributed`` over a coordinator on 127.0.0.1.

* ``jaxstyle sweep --distributed``: the (set, rate) pairs split over both processes' devices give
  the one-process run's results (same keys: the same losses and chosen rates), and only process 0
  writes (process 1 is pointed at a copy of the run folder, which it leaves untouched).
* ``jaxstyle lpn --distributed``: data-parallel LPN-FiLM training over both processes equals the
  one-process run's epoch (losses within float tolerance); only process 0 writes.
* A process that dies makes the other stop within seconds with one line naming it.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jaxstyle import cli

pytestmark = pytest.mark.filterwarnings("ignore:style .* the last 1 cycle:UserWarning")

SWEEP = ["--seconds", "3", "--sweep-epochs", "2", "--rates", "0.3", "0.5", "--quiet"]
LPN = ["--styles", "Neutral", "Crouched", "--new-styles", "Limping", "--gaits", "FW", "--epochs", "1", "--hidden", "8",
       "--generator-hidden", "16", "--filters", "4", "--finetune-steps", "0", "--quiet"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(argv, process: int, port: int, *, by_env: bool = False, extra_env=None) -> subprocess.Popen:
    """``jaxstyle ARGV --distributed`` as process ``process`` of 2; the coordinator, count and id
    given as flags, or (``by_env``) as the JAX_* environment variables."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", **(extra_env or {})}
    argv = [sys.executable, "-m", "jaxstyle.cli", *map(str, argv), "--distributed"]
    if by_env:
        env.update(JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}", JAX_NUM_PROCESSES="2", JAX_PROCESS_ID=str(process))
    else:
        argv += ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(process)]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(procs, timeout: float = 150.0) -> list[tuple[int, str, str]]:
    out = []
    for p in procs:
        try:
            stdout, stderr = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            for q in procs:
                q.kill()
            pytest.fail("a --distributed process hung")
        out.append((p.returncode, stdout, stderr))
    return out


def snapshot(folder: Path) -> dict:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*")}


def rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def base_run(tmp_path_factory) -> tuple[Path, Path]:
    """Tiny procedural data and a tiny 2018 base trained on its Neutral walk (one process)."""
    root = tmp_path_factory.mktemp("dist")
    data = root / "data"
    assert cli.main(["data", "generate", "--out", str(data), "--styles", "Neutral", "Crouched", "Limping",
                     "--seconds", "10", "--quiet"]) == 0
    run = root / "run"
    assert cli.main(["train-base", "--data", str(data), "--run", str(run), "--styles", "Neutral", "--fewshot-styles",
                     "Limping", "Crouched", "--gaits", "FW", "--hidden", "16", "--rank", "2", "--base-epochs", "1",
                     "--quiet"]) == 0
    return data, run


@pytest.mark.slow  # 32 s, and under the default run's two busy workers its coordinator can time out
def test_two_process_sweep_equals_the_one_process_sweep(base_run, tmp_path):
    _, run = base_run
    one, zero, other = (tmp_path / n for n in ("one", "zero", "other"))
    for folder in (one, zero, other):
        shutil.copytree(run, folder)
    before = snapshot(other)
    port = free_port()
    procs = [start(["sweep", "--run", zero, *SWEEP], 0, port), start(["sweep", "--run", other, *SWEEP], 1, port,
                                                                     by_env=True)]
    assert cli.main(["sweep", "--run", str(one), *SWEEP]) == 0  # the one-process reference, meanwhile
    for rc, _, stderr in finish(procs):
        assert rc == 0, stderr[-3000:]
    a, b = rows(one / "sweep" / "results.csv"), rows(zero / "sweep" / "results.csv")
    assert [(r["style"], r["rate"]) for r in a] == [(r["style"], r["rate"]) for r in b] and len(a) == 4
    for key in ("train_loss", "validation_loss", "rollout_bone_error", "rollout_skating_m_s"):
        np.testing.assert_allclose([float(r[key]) for r in b], [float(r[key]) for r in a], rtol=1e-5)
    assert json.loads((zero / "sweep" / "chosen_rates.json").read_text()) == \
        json.loads((one / "sweep" / "chosen_rates.json").read_text())
    assert (zero / "sweep" / "sweep.json").is_file()
    assert snapshot(other) == before  # process 1 read its base and wrote nothing


@pytest.mark.slow  # python -m pytest -m slow: the default run checks the LPN's sharded step in one process
# (test_lpn_sharded.py); this one adds two more JAX processes on 2 cores
def test_two_process_lpn_training_equals_the_one_process_run(base_run, tmp_path):
    data, _ = base_run
    port = free_port()
    two = [*LPN[:LPN.index("--epochs")], "--epochs", "2", *LPN[LPN.index("--epochs") + 2:]]  # epochs to choose from
    procs = [start(["lpn", "--data", data, "--run", tmp_path / "zero", *two], 0, port),
             start(["lpn", "--data", data, "--run", tmp_path / "other", *two], 1, port)]
    assert cli.main(["lpn", "--data", str(data), "--run", str(tmp_path / "one"), *two]) == 0
    for rc, _, stderr in finish(procs):
        assert rc == 0, stderr[-3000:]
    a, b = rows(tmp_path / "one" / "lpn" / "log.csv"), rows(tmp_path / "zero" / "lpn" / "log.csv")
    assert len(a) == len(b) == 2
    for key in ("train_loss", "train_mse", "train_bll", "val_mse", "val_bll"):
        np.testing.assert_allclose([float(r[key]) for r in b], [float(r[key]) for r in a], rtol=1e-4)
    assert (tmp_path / "zero" / "lpn" / "results.md").is_file()
    # the one-process run chose among its two epochs; the two processes kept the last, as they say
    assert (tmp_path / "one" / "lpn" / "chosen_epoch.json").is_file()
    assert not (tmp_path / "zero" / "lpn" / "chosen_epoch.json").exists()
    assert "epoch is chosen only in a one-process run" in (tmp_path / "zero" / "log.txt").read_text()
    assert not (tmp_path / "other").exists()  # process 1 wrote nothing


@pytest.mark.slow  # 13 s
def test_a_dead_process_stops_the_other_with_one_line(base_run, tmp_path):
    _, run = base_run
    shutil.copytree(run, tmp_path / "zero")
    shutil.copytree(run, tmp_path / "other")
    long = ["--seconds", "3", "--sweep-epochs", "100000", "--rates", "0.3", "--quiet"]
    port = free_port()
    fast = {"JAXSTYLE_WATCH_S": "4"}
    procs = [start(["sweep", "--run", tmp_path / "zero", *long], 0, port, extra_env=fast),
             start(["sweep", "--run", tmp_path / "other", *long], 1, port, extra_env=fast)]
    line = procs[0].stdout.readline()  # process 0 reports once its base is loaded
    assert line.startswith("sweep on"), line
    time.sleep(2.0)
    procs[1].send_signal(signal.SIGKILL)
    t0 = time.perf_counter()
    rc, _, stderr = finish(procs[:1], timeout=60)[0]
    procs[1].wait()
    assert rc == 1 and time.perf_counter() - t0 < 30
    assert stderr.strip().splitlines()[-1] == ("jaxstyle: error: process 0 of 2: process 1 stopped answering 4 s ago "
                                                "(it exited with an error or died; see its output); stopping too")
