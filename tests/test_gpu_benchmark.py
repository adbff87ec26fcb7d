"""``python benchmarks/gpu.py --small`` (the accelerator benchmark at a size a CPU runs) finishes
and writes its JSON and markdown with every section's figures."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # about 35 s on 2 CPU cores: python -m pytest -m slow
def test_gpu_benchmark_small_runs_on_cpu(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gpu.py"), "--small", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    result = json.loads((tmp_path / "gpu.json").read_text())
    assert "errors" not in result and result["small"]
    assert [r["mode"] for r in result["sweep"]] == ["paper", "fast"]
    for r in result["sweep"]:
        assert r["pairs"] == 4 and r["steps"] > 0 and r["seconds"] > 0 and r["gflop_s"] > 0
    assert result["lpn"][0]["samples"] == 20 * 32 and result["lpn"][0]["samples_per_s"] > 0
    assert [r["characters"] for r in result["live"]] == [16]
    assert all(0 < r["p50_ms"] <= r["p95_ms"] for r in result["live"])
    table = (tmp_path / "gpu.md").read_text()
    assert "| paper | 2 x 2 |" in table and "| LPN FiLM | 32 | 32 | 20 |" in table and "FAILED" not in table
