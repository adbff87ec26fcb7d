"""Run folders never lose a result: one writing command at a time (an advisory lock naming its
holder, released however the holder ends), few-shot reports merged rather than replaced, damaged
or hand-edited result files refused with the file and the key, never reset."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from jaxstyle.cli.common import CLIError, Run, lock_run
from jaxstyle.cli.main import main
from jaxstyle.data import folders
from jaxstyle.data.folders import PipelineError
from jaxstyle.mason2018 import fewshot, selection, sweep_files
from jaxstyle.nn import pfnn
from jaxstyle.train import defaults

MODEL = pfnn.PFNNConfig(input_size=6, hidden_size=8, output_size=5, rank=2)


def fake_result(styles, rates=(0.1, 0.5), seed=0) -> selection.SweepResult:
    """A sweep result of random adapters and losses (the report's plumbing, not a sweep)."""
    S, R = len(styles), len(rates)
    keys = jax.random.split(jax.random.PRNGKey(seed), S * R)
    adapters = jax.tree.map(lambda *v: np.stack(v).reshape((S, R) + v[0].shape),
                            *[pfnn.init_adapter(k, MODEL) for k in keys])
    rng = np.random.default_rng(seed)
    val = rng.uniform(0.1, 1.0, (S, R))
    rollout = {k: rng.uniform(0, 1, (S, R)) for k in defaults.ROLLOUT_FIELDS}
    rollout["passed"] = np.ones((S, R), bool)
    return selection.SweepResult(tuple(styles), tuple(rates), adapters, val + 0.1, val, rollout, {},
                                 np.argmin(val, 1), np.ones(S, bool), (100,) * S, (30,) * S, {"sweep": 1.0})


def test_a_sweep_report_adds_to_the_earlier_sets_and_replace_starts_over(tmp_path):
    config = fewshot.SweepConfig(model=MODEL, epochs=1, rates=(0.1, 0.5))
    sweep_files.write_report(fake_result(["Angry", "Proud"]), tmp_path, config)
    again = fake_result(["Proud", "Zombie"], seed=1)
    paths = sweep_files.write_report(again, tmp_path, config)
    chosen = sweep_files.read_chosen(paths["chosen"])
    assert set(chosen) == {"Angry", "Proud", "Zombie"}
    assert chosen["Proud"]["rate"] == again.chosen_rate("Proud")  # swept again: updated
    with open(paths["csv"], newline="") as f:
        table = list(csv.DictReader(f))
    assert [r["style"] for r in table] == ["Angry"] * 2 + ["Proud"] * 2 + ["Zombie"] * 2
    assert sorted(p.name for p in paths["adapters"].iterdir()) == ["Angry", "Proud", "Zombie"]
    loaded = sweep_files.load_adapter(paths["adapters"] / "Proud", MODEL)
    for p, q in zip(jax.tree.leaves(loaded), jax.tree.leaves(again.adapter("Proud")), strict=True):
        np.testing.assert_array_equal(np.asarray(p), np.asarray(q))
    paths = sweep_files.write_report(fake_result(["Zombie"], seed=2), tmp_path, config, replace=True)
    assert set(sweep_files.read_chosen(paths["chosen"])) == {"Zombie"}
    assert [p.name for p in paths["adapters"].iterdir()] == ["Zombie"]


@pytest.mark.parametrize("text, message", [
    ('{"Angry": {"rate": 0.3,}}', r"chosen_rates\.json, line 1: not valid JSON"),
    ('{"Angry": {"validation_loss": 1.0}}', r"chosen_rates\.json: 'Angry': expected an object with a 'rate'"),
    ('{"Angry": {"rate": "0.3"}}', r"'Angry': 'rate' must be a dropout rate in \[0, 1\), got \"0\.3\""),
    ('{"Angry": {"rate": NaN}}', r"'Angry': 'rate' must be a dropout rate in \[0, 1\), got NaN"),
    ('{"Angry": {"rate": 7}}', r"'Angry': 'rate' must be a dropout rate in \[0, 1\), got 7"),
    ('{"Angry": {"rate": [0.3]}}', r"'Angry': 'rate' must be a dropout rate"),
    ('{"Angry": {"rate": 0.3, "passed_check": "yes"}}', r"'Angry': 'passed_check' must be true or false"),
    ('[0.3]', r"expected an object of set name -> chosen rate, got list"),
])
def test_hand_edited_chosen_rates_are_refused_with_the_file_and_key(tmp_path, text, message):
    path = tmp_path / "chosen_rates.json"
    path.write_text(text)
    with pytest.raises(PipelineError, match=message):
        sweep_files.read_chosen(path)
    # and a sweep report into that folder refuses it too instead of dropping the earlier sets
    with pytest.raises(PipelineError, match=message):
        sweep_files.write_report(fake_result(["Proud"]), tmp_path, fewshot.SweepConfig(model=MODEL, epochs=1,
                                                                                        rates=(0.1, 0.5)))
    assert path.read_text() == text


def test_one_writer_per_run_folder_and_a_killed_holder_frees_it(tmp_path, capsys):
    first = Run(tmp_path, "sweep", {}, ["sweep", "--run", str(tmp_path)])
    with pytest.raises(CLIError, match=r"in use by pid \d+ \(jaxstyle sweep --run .*\); wait until it finishes"):
        Run(tmp_path, "train-base", {}, ["train-base"])
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "base.json").write_text("{}")  # past the command's check for a base
    assert main(["sweep", "--run", str(tmp_path), "--seconds", "1"]) == 1  # the command line says the same
    assert "in use by pid" in capsys.readouterr().err
    first.close()
    Run(tmp_path, "sweep", {}, ["sweep"]).close()  # free again
    # a holder killed (SIGKILL, no clean-up) leaves no stale lock: the system releases it
    code = textwrap.dedent(f"""
        import sys, time
        from pathlib import Path
        from jaxstyle.cli.common import lock_run
        held = lock_run(Path({str(tmp_path)!r}), ["lpn"])
        print("held", flush=True)
        time.sleep(60)
    """)
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(CLIError, match=rf"in use by pid {holder.pid} \(jaxstyle lpn\)"):
            lock_run(tmp_path, ["sweep"])
    finally:
        holder.kill()
        holder.wait()
    lock_run(tmp_path, ["sweep"]).close()


def test_a_damaged_config_json_is_refused_and_kept(tmp_path, capsys):
    config = tmp_path / "config.json"
    text = '{\n  "demo": {"epochs": 3},\n}\n'
    config.write_text(text)
    (tmp_path / "base").mkdir()
    (tmp_path / "base" / "base.json").write_text("{}")  # past the command's check for a base
    assert main(["sweep", "--run", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"jaxstyle sweep: error: {config}, line 3: not valid JSON") and "\n" not in err
    assert config.read_text() == text
    config.write_text(json.dumps({"demo": {"epochs": 3}}))
    Run(tmp_path, "sweep", {"sets": ["Angry"]}, ["sweep"]).close()
    assert json.loads(config.read_text()) == {"demo": {"epochs": 3}, "sweep": {"sets": ["Angry"]}}


def test_an_adapter_of_a_base_of_other_sizes_is_named_as_such_not_as_damage(tmp_path):
    from jaxstyle.train.checkpoint import CheckpointMismatchError

    config = fewshot.SweepConfig(model=MODEL, epochs=1, rates=(0.1, 0.5))
    paths = sweep_files.write_report(fake_result(["Angry"]), tmp_path, config)
    other = pfnn.PFNNConfig(input_size=6, hidden_size=8, output_size=5, rank=4)
    # rank 2 saved, rank 4 asked for: which array orbax reports first varies
    with pytest.raises(CheckpointMismatchError, match=r"of a model of other sizes: an array is \((.*\b)?2(\b.*)?\) "
                                                      r"there and \((.*\b)?4(\b.*)?\) in this model"):
        sweep_files.load_adapter(paths["adapters"] / "Angry", other)
    assert not (paths["adapters"] / "Angry" / "damaged").exists()
    assert sweep_files.load_adapter(paths["adapters"] / "Angry", MODEL) is not None  # its own model still reads it


def test_paths_inside_a_run_folder_are_recorded_relative_to_it(tmp_path, monkeypatch):
    from jaxstyle.data.folders import located_path, portable_path

    run = tmp_path / "runs" / "a"
    (run / "data" / "Angry").mkdir(parents=True)
    clip = run / "data" / "Angry" / "Angry_FW.bvh"
    clip.write_text("x")
    outside = tmp_path / "elsewhere.bvh"
    monkeypatch.chdir(tmp_path)
    assert portable_path("runs/a/data/Angry/Angry_FW.bvh", run / "lpn") == "../data/Angry/Angry_FW.bvh"
    assert portable_path(outside, run / "lpn") == str(outside)  # outside the run folder: absolute
    assert located_path("../data/Angry/Angry_FW.bvh", run / "lpn") == str(clip.resolve())
    moved = tmp_path / "moved"
    run.rename(moved)
    monkeypatch.chdir(tmp_path / "runs")  # another directory
    assert located_path("../data/Angry/Angry_FW.bvh", moved / "lpn") == str((moved / "data/Angry/Angry_FW.bvh"
                                                                              ).resolve())


def test_a_clip_with_the_bases_joints_in_another_order_is_refused(tmp_path):
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.motion.bvh import read_bvh, write_bvh
    from tests.test_play import tiny_model

    base = tiny_model(tmp_path).base
    motion = read_bvh(base.dataset.specs[0].path)
    # the same hierarchy written with the children of the first joint that has several in reverse
    # order (e.g. the right leg before the left): a valid BVH of the base's joints in another order
    children = {j: [c for c in range(motion.num_joints) if motion.parents[c] == j] for j in range(motion.num_joints)}
    fork = next(j for j in range(motion.num_joints) if len(children[j]) > 1)
    order, stack = [], [0]
    while stack:
        j = stack.pop()
        order.append(j)
        kids = children[j][::-1] if j == fork else children[j]
        stack.extend(kids[::-1])
    k = next(i for i, j in enumerate(order) if i != j)
    a, b = k, order[k]
    where = {old: new for new, old in enumerate(order)}
    swapped = motion.replace(names=tuple(motion.names[j] for j in order),
                             parents=np.array([-1 if motion.parents[j] < 0 else where[motion.parents[j]]
                                               for j in order]),
                             offsets=motion.offsets[order], rotations=motion.rotations[:, order],
                             local_positions=motion.local_positions[:, order],
                             channels=tuple(motion.channels[j] for j in order),
                             end_site_parents=np.array([where[p] for p in motion.end_site_parents], dtype=np.int64))
    clip = tmp_path / "Swapped.bvh"
    write_bvh(swapped, clip)
    specs = folders.user_clip_specs([clip], False, None)
    with pytest.raises(PipelineError, match=rf"Swapped\.bvh: its joints are the base's in another order \(joint {a} "
                                            rf"is '{motion.names[b]}', the base's is '{motion.names[a]}'\)"):
        pipeline.run_sweep(base, specs, fewshot.SweepConfig(epochs=1, rates=(0.3,)), progress=False)
    assert not (tmp_path / "sweep").exists()
