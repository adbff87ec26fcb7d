"""Few-shot model selection: hold-out, the selection rule, lifelong styles, the report."""

from __future__ import annotations

import csv
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxstyle.data import datasets
from jaxstyle.data.clips import ClipSpec
from jaxstyle.mason2018 import fewshot, selection, sweep_files
from jaxstyle.nn import pfnn
from jaxstyle.output import check as check_lib
from jaxstyle.train import defaults, scan
from tests.test_fewshot import SMALL, _data


def test_choose_rates_rule():
    val = np.array([[0.5, 0.4, 0.6],    # best rate fails the check -> next best passing
                    [0.3, 0.2, 0.1],    # best passes
                    [0.3, 0.2, 0.4],    # none passes -> best overall, flagged
                    [np.nan, 0.9, 0.8]])
    passed = np.array([[1, 0, 1], [1, 1, 1], [0, 0, 0], [1, 1, 0]], bool)
    chosen, ok = check_lib.choose_rates(val, passed)
    np.testing.assert_array_equal(chosen, [0, 2, 1, 1])
    np.testing.assert_array_equal(ok, [True, True, False, True])


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_adding_a_style_leaves_the_others_unchanged():
    """The lifelong property: a new few-shot style (appended) gets its own adapter, keys and
    batches; every earlier style's adapter, and so its outputs, stay the same."""
    x, y, phase, rows = _data()
    config = fewshot.SweepConfig(model=SMALL, epochs=3, batch_size=16, learning_rate=3e-3, rates=(0.0, 0.4))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    two = [rows[1], rows[2]]
    three = two + [rows[0]]  # the new style is the longest: more (masked) steps for the others
    b2, m2 = scan.sweep_batches(two, config.epochs, config.batch_size)
    b3, m3 = scan.sweep_batches(three, config.epochs, config.batch_size)
    assert b3.shape[1] > b2.shape[1]
    before, _ = fewshot.adapter_sweep(params, x, y, phase, b2, m2, config)
    after, _ = fewshot.adapter_sweep(params, x, y, phase, b3, m3, config)
    for s in range(2):
        for r in range(2):
            a, b = (jax.tree.map(lambda v, s=s, r=r: v[s, r], t) for t in (before, after))
            out_a = pfnn.pfnn_apply(params, x, phase, adapter=a)
            out_b = pfnn.pfnn_apply(params, x, phase, adapter=b)
            np.testing.assert_allclose(np.asarray(out_b), np.asarray(out_a), rtol=1e-5, atol=1e-6)


def test_chunked_sweep_equals_one_call():
    x, y, phase, rows = _data(3)
    config = fewshot.SweepConfig(model=SMALL, epochs=3, batch_size=16, learning_rate=3e-3, rates=(0.2, 0.5))
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), SMALL)
    b, m = scan.sweep_batches(rows, config.epochs, config.batch_size)
    whole, lw = fewshot.adapter_sweep(params, x, y, phase, b, m, config)
    # 12 steps: 5 + 5 + 2
    chunked, lc = fewshot.adapter_sweep(params, x, y, phase, b, m, config, run=scan.GridRun(chunk_steps=5))
    for p, q in zip(jax.tree.leaves(whole), jax.tree.leaves(chunked), strict=True):
        np.testing.assert_allclose(np.asarray(q), np.asarray(p), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(np.asarray(lc), np.asarray(lw), rtol=1e-5)


@pytest.fixture(scope="module")
def fewshot_set(mocap):
    """Two 100STYLE sets of 4 s (+ the trajectory window) each, with mirrors."""
    root = mocap / "100style"
    specs = []
    for name, path, start in (("Elated", "Elated/Elated_FW.bvh", 482), ("Rushed", "Rushed/Rushed_FW.bvh", 343)):
        specs += [ClipSpec(str(root / path), name, start, start + 240 + 111, mirror) for mirror in (False, True)]
    return datasets.build_pfnn_dataset(specs), specs


def test_holdout_keeps_the_last_cycle_of_each_clip(fewshot_set):
    dataset, _ = fewshot_set
    train, val = selection.holdout_rows(dataset, "Elated", gap_seconds=0.25)
    phase = dataset.phases[:, 0]
    for clip in np.unique(dataset.clip[dataset.rows_of_style("Elated")]):
        t = train[dataset.clip[train] == clip]
        v = val[dataset.clip[val] == clip]
        assert dataset.frame[t].max() + 15 < dataset.frame[v].min()  # the gap
        progress = np.sum(np.mod(np.diff(phase[v]), 1.0))
        assert 0.9 < progress < 1.0  # one cycle, less one frame's step
        assert len(v) < 0.34 * (len(v) + len(t) + 15) + 1
    # mirrored twins hold out the same frames
    f = [np.sort(dataset.frame[val[dataset.clip[val] == c]]) for c in (0, 1)]
    np.testing.assert_array_equal(f[0], f[1])
    with pytest.raises(ValueError, match="too few"):
        selection.holdout_rows(dataset, "Elated", gap_seconds=10.0)
    # a cycle longer than the cap is capped, with a warning naming the style and the file
    with pytest.warns(UserWarning, match=r"'Elated'.*Elated_FW\.bvh.*holding out"):
        _, capped = selection.holdout_rows(dataset, "Elated", max_fraction=0.1)
    assert len(capped) < 0.5 * len(val)


@pytest.mark.slow  # python -m pytest -m slow; the default run covers the same code more cheaply
def test_fewshot_sweep_end_to_end_writes_a_report(fewshot_set, tmp_path):
    """An untrained base, 2 epochs: checks the plumbing (shapes, files, round trips), not quality."""
    dataset, specs = fewshot_set
    skeleton = datasets.load_clip(specs[0], fps=60.0)
    model = pfnn.PFNNConfig(input_size=dataset.inputs.shape[1], hidden_size=64, output_size=dataset.outputs.shape[1],
                            rank=8)
    params = pfnn.init_pfnn(jax.random.PRNGKey(0), model)
    config = fewshot.SweepConfig(model=model, epochs=2, rates=(0.3, 0.7))
    options = selection.FewshotOptions(check=defaults.RolloutCheck(seconds=1.0), run=scan.GridRun(chunk_steps=100))
    result = selection.fewshot_sweep(params, dataset.normalisers(), dataset, skeleton, config, options)
    assert result.styles == ("Elated", "Rushed")
    assert result.validation_loss.shape == (2, 2) and np.isfinite(result.validation_loss).all()
    for k in defaults.ROLLOUT_FIELDS:
        assert result.rollout[k].shape == (2, 2)
    # the validation loss is the MSE of the held-out rows, recomputed here without vmap
    data = selection.fewshot_data(dataset, dataset.normalisers())
    rows = data.val_rows[1]
    a = result.adapter("Rushed", 1)
    want = jnp.mean((pfnn.pfnn_apply(params, data.x[rows], data.phase[rows], adapter=a) - data.y[rows]) ** 2)
    np.testing.assert_allclose(result.validation_loss[1, 1], float(want), rtol=1e-5)

    paths = sweep_files.write_report(result, tmp_path, config)
    with open(paths["csv"], newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == 4 and sum(int(r["chosen"]) for r in table) == 2
    chosen = json.loads(paths["chosen"].read_text())
    assert set(chosen) == {"Elated", "Rushed"}
    assert chosen["Rushed"]["rate"] == result.chosen_rate("Rushed")
    assert paths["heatmap"].stat().st_size > 1000
    loaded = sweep_files.load_adapter(paths["adapters"] / "Rushed", model)
    for p, q in zip(jax.tree.leaves(loaded), jax.tree.leaves(result.adapter("Rushed")), strict=True):
        np.testing.assert_array_equal(np.asarray(p), np.asarray(q))


def test_each_check_criterion_can_fail_a_pair():
    check = defaults.RolloutCheck()
    good = {"finite": 1.0, "bone_error": 0.03, "contact_fraction": 0.95, "skating_m_s": 0.3, "progress": 1.0}
    ref = {"contact_fraction": np.array([1.0]), "skating_m_s": np.array([0.1]), "speed_m_s": np.array([1.2]),
           "base_skating_m_s": np.array([0.3]), "base_bone_error": np.array([0.03])}
    bad = [("finite", 0.0), ("bone_error", 0.2), ("contact_fraction", 0.3), ("skating_m_s", 0.6),
           ("progress", 0.3), ("progress", 2.5)]
    out = {k: np.array([[v] * (len(bad) + 1)]) for k, v in good.items()}
    for r, (k, v) in enumerate(bad, start=1):
        out[k][0, r] = v
    passed = check_lib.passes_check(out, ref["contact_fraction"], ref["base_skating_m_s"], ref["speed_m_s"], check)
    np.testing.assert_array_equal(passed[0], [True] + [False] * len(bad))
    # the refusal's wording names exactly the criterion each pair fails, nothing for the passing one
    named = {"finite": "did not stay finite", "bone_error": "bone error", "contact_fraction": "feet on the floor",
             "skating_m_s": "foot skating", "progress": "travelled"}
    for r in range(len(bad) + 1):
        why = check_lib.failed_criteria({k: float(v[0, r]) for k, v in out.items()}, 1.0, 0.3, 1.2, check)
        assert why == [] if r == 0 else (len(why) == 1 and named[bad[r - 1][0]] in why[0]), (r, why)
    # a style that stands still is not held to the distance
    still = dict(ref, speed_m_s=np.array([0.0]))
    assert check_lib.passes_check({k: v[:, [0, 5]] for k, v in out.items()}, still["contact_fraction"],
                                  still["base_skating_m_s"], still["speed_m_s"], check).all()


def test_judge_pairs_measures_every_pair_against_the_base_column(mocap):
    """The one judgement of both papers' checks: a captured walk as the pairs' and the base's
    rollout passes (no bone error, the capture's contacts, the base's skating, the path's length),
    a pair that diverged or slides beyond the base fails, and the last column is the base's."""
    from jaxstyle.labels.contacts import FootJoints, estimate_units_per_meter, floor_heights
    from jaxstyle.motion.bvh import read_bvh
    from jaxstyle.motion.kinematics import UP_AXIS, global_positions
    from jaxstyle.output import metrics

    motion = read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh")
    pos = global_positions(motion)[:300]
    fps, upm = float(motion.fps), estimate_units_per_meter(motion)
    feet = list(FootJoints.find(motion).ankles) + list(FootJoints.find(motion).toes)
    floor = floor_heights(pos[:, feet, UP_AXIS])
    origin = pos[:, 0, [0, 2]]
    check = defaults.RolloutCheck(seconds=len(pos) / fps)
    speed = float(np.sum(np.linalg.norm(np.diff(origin, axis=0), axis=-1))) / check.seconds  # units / s
    real = metrics.positions_foot_stats(pos, motion, fps, floor, units_per_meter=upm, tolerance_m=check.tolerance_m)
    sliding = pos.copy()
    sliding[:, :, 0] += np.linspace(0, 3.0 * upm, len(pos))[:, None]  # every joint, feet too, slides 3 m more
    diverged = np.where(np.arange(len(pos))[:, None, None] == 100, np.nan, pos)
    columns = [pos, sliding, diverged, pos]  # three pairs, then the base
    out, base = check_lib.judge_pairs([columns], [[origin, origin + (sliding - pos)[:, 0, [0, 2]], origin, origin]],
                                      np.array([[True, True, False, True]]), check_lib.Judging(motion, fps, upm, check),
                                      check_lib.Captures([floor], np.array([speed]), np.array([real.contact_fraction])))
    assert out["finite"].shape == (1, 3)
    np.testing.assert_array_equal(out["passed"][0], [1.0, 0.0, 0.0])
    why = [check_lib.failed_criteria({k: float(v[0, r]) for k, v in out.items()}, real.contact_fraction,
                                     base["base_skating_m_s"][0], speed / upm, check) for r in range(3)]
    assert why[0] == [] and why[2] == ["the rollout did not stay finite"]
    assert [w.split(" ")[0] for w in why[1]] == ["foot"]  # slides: the skating criterion, nothing else
    np.testing.assert_allclose(out["progress"][0, 0], 1.0)
    assert out["skating_m_s"][0, 1] > out["skating_m_s"][0, 0] == pytest.approx(base["base_skating_m_s"][0])
    assert np.isnan(out["bone_error"][0, 2]) and base["base_bone_error"][0] < 1e-3
