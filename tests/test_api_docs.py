"""The examples of docs/api.md run as written, in order, as one script (one per public entry)."""

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def api_examples() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(), flags=re.S)


def test_every_section_of_the_api_page_has_one_example():
    text = (ROOT / "docs" / "api.md").read_text()
    sections = [s for s in text.split("\n## ")[1:] if not s.startswith("Modules by job")]
    assert len(sections) >= 7
    for s in sections:
        assert s.count("```python") == 1, s.splitlines()[0]


def test_api_examples_run_as_written(tmp_path):
    (tmp_path / "api.py").write_text("\n".join(api_examples()))
    proc = subprocess.run([sys.executable, "api.py"], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    assert "| Proud_FW | " in out                                           # the sweep table
    assert "| Proud (few-shot) | straight" in out                          # synthesis's quality table
    assert "| 2018 PFNN | Proud (few-shot) | stop_and_go" in out            # the benchmark's table (a mark may follow)
    assert "(240, " in out                                                 # the PFNN rollout: 4 s at 60 fps
    assert "(1, 120, " in out                                               # the LPN character: 2 s, one path
    assert (tmp_path / "api" / "synthesis" / "straight.gif").is_file()
    assert len(list((tmp_path / "api" / "synthesis" / "bvh").glob("*.bvh"))) == 3
    assert (tmp_path / "api" / "mirrored.bvh").is_file()
