"""The README's Python tour runs as written."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_tour() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("## A 20-line API tour", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 1, "the tour section holds one python block"
    return blocks[0]


def test_readme_tour_is_twenty_lines():
    assert len(readme_tour().strip().splitlines()) <= 20


def test_readme_tour_runs_as_written(tmp_path):
    (tmp_path / "tour.py").write_text(readme_tour())
    proc = subprocess.run([sys.executable, "tour.py"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "| Proud_FW | " in proc.stdout                        # the sweep table
    assert "| Proud_FW (few-shot, rate " in proc.stdout           # the quality table
    out = tmp_path / "tour"
    assert (out / "sweep" / "chosen_rates.json").is_file()
    assert (out / "synthesis" / "circle.gif").is_file()
    assert len(list((out / "synthesis" / "bvh").glob("*.bvh"))) == 2
