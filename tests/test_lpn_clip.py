"""New styles the 2022 way from the user's own BVH clips (:func:`jaxstyle.mason2022.finetune.finetune_clips`,
``jaxstyle lpn --clip``): one vmapped FiLM-generator sweep over rates, validation, a closed-loop
check with the 2022 controller, a chosen rate, the generator written; bad clips refused in one line.

Tiny procedural data (:mod:`jaxstyle.data.procedural`) and a tiny LPN-FiLM: these check the
plumbing and the bookkeeping against independent recomputations, not the quality."""

from __future__ import annotations

import json
import re

import jax
import numpy as np
import pytest

from jaxstyle import cli
from jaxstyle.control import loop, lpn_controller, lpn_phases
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import rollout
from jaxstyle.data import procedural
from jaxstyle.data.folders import PipelineError
from jaxstyle.data.lpn_features import bone_points
from jaxstyle.mason2022 import finetune, pipeline, report, styledata
from jaxstyle.nn import film_generator as film
from jaxstyle.output import check as check_lib
from jaxstyle.train import defaults
from jaxstyle.train.defaults import PHASE_FLOOR

TINY = {"hidden": 8, "generator_hidden": 16, "filters": 4}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A base style folder (Neutral) and, elsewhere, the user's clip (a Limping walk of 12 s)."""
    base = procedural.write_dataset(tmp_path_factory.mktemp("base") / "p", ["Neutral"], ("FW",), seconds=10)
    user = procedural.write_dataset(tmp_path_factory.mktemp("user") / "p", ["Limping"], ("FW",), seconds=12)
    return base, user / "Limping" / "Limping_FW.bvh", tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def base_data(folders):
    root, _, cache = folders
    return pipeline.build_data(root, ("Neutral",), cache=cache)


@pytest.fixture(scope="module")
def model(base_data, tmp_path_factory):
    config = pipeline.model_config(base_data.base, **TINY)
    return base_data, pipeline.train_model(base_data, config, tmp_path_factory.mktemp("m") / "lpn", epochs=1,
                                           progress=False)


def test_choose_checked_prefers_passing_rates():
    val = np.array([[0.1, 0.2, 0.3], [0.3, 0.2, 0.1], [np.nan, 0.5, 0.4]])
    passed = np.array([[0, 1, 1], [0, 0, 0], [1, 0, 1]], bool)
    chosen, any_pass = check_lib.choose_rates(val, passed)
    assert chosen.tolist() == [1, 2, 2] and any_pass.tolist() == [True, False, True]


def test_film_sweep_from_a_user_clip_chooses_a_rate_and_writes_its_generator(folders, model, tmp_path):
    _, clip, cache = folders
    data, m = model
    data = finetune.user_clip_data(data, [clip], mirror=False, cache=cache)
    assert data.new.styles == ("Limping_FW",) and len(data.new.specs) == 1
    rates = (0.1, 0.5)
    result, checked, paths = finetune.finetune_clips(m, data, tmp_path / "out", rates=rates, steps=3, progress=False)
    assert result.styles == ("Limping_FW",) and result.rates == rates and result.steps == 3
    for k in defaults.ROLLOUT_FIELDS:
        assert checked[k].shape == (1, 2)
    # the choice: the lowest validation loss among the rates that passed the check (else among all)
    val = result.after["validation"]["mse"] + result.after["validation"]["bll"]
    ok = checked["passed"][0].astype(bool)
    expect = int(np.argmin(np.where(ok, val[0], np.inf))) if ok.any() else int(np.argmin(val[0]))
    assert int(result.chosen[0]) == expect and result.chosen_rate("Limping_FW") in rates
    # the fine-tuned generators differ from the base's and from each other (the rates differ)
    g0 = m.params["style"]["generator"]
    tuned = [result.params(m, "Limping_FW", r)["style"]["generator"] for r in range(2)]
    leaf = lambda g: np.asarray(jax.tree.leaves(g)[-1])  # noqa: E731
    assert not np.allclose(leaf(tuned[0]), leaf(g0)) and not np.allclose(leaf(tuned[0]), leaf(tuned[1]))
    # the chosen generator is written and loads back exactly
    loaded = finetune.load_generator(paths["generator Limping_FW"], g0)
    jax.tree.map(np.testing.assert_array_equal, loaded, tuned[int(result.chosen[0])])
    chosen = json.loads(paths["chosen"].read_text())["Limping_FW"]
    assert chosen["rate"] == result.chosen_rate("Limping_FW") and isinstance(chosen["check_passed"], bool)
    assert json.loads(paths["clips"].read_text())["new"][0]["path"] == str(clip)
    # the check's rollout of the chosen pair, recomputed alone with the controller
    new, c = result.data, int(result.chosen[0])
    vec = film.clip_films(loaded, new.clips[new.train_clips[0]]).mean(axis=0)
    rows = new.train_rows[0]
    start = rows[np.argmin(data.new.frame[rows])]
    fps = data.skeleton.fps
    y = data.new.outputs[rows]
    speed = float(np.median(np.hypot(y[:, 0], y[:, 6]))) * fps
    floor = PHASE_FLOOR * lpn_phases.capture_phase_rate(data.new, "Limping_FW")  # the default runtime's
    state = lpn_controller.initial_state(data.new.inputs[start], data.new.phases[start],
                                         len(bone_points(data.skeleton)[0]), phase_floor=floor)
    controls = loop.turning_path(int(round(5 * fps)), speed, np.deg2rad(45.0), fps)
    alone = rollout(StyleNetModel.create(m.params, m.config, data.base.normalisers()), vec, state, controls)
    origin = np.asarray(alone.origin)
    progress = np.sum(np.linalg.norm(np.diff(origin, axis=0), axis=-1)) / (speed * 5.0)
    np.testing.assert_allclose(checked["progress"][0, c], progress, rtol=1e-4)
    lines = report.check_table(result, checked)
    assert lines[2].startswith("| Limping_FW | ") and ("passed" in lines[2] or "FAILED" in lines[2])


def test_bad_user_clips_are_refused_in_one_line(folders, base_data, tmp_path):
    _, clip, cache = folders
    data = base_data
    with pytest.raises(PipelineError, match=r"shorter than the trajectory window") as e:
        finetune.user_clip_data(data, [clip], seconds=(0.0, 1.0), cache=cache)
    assert "\n" not in str(e.value) and str(clip) in str(e.value)
    with pytest.raises(PipelineError, match=r"no 240-frame style clip inside its training rows") as e:
        finetune.user_clip_data(data, [clip], seconds=(0.0, 4.5), cache=cache)
    assert "\n" not in str(e.value)
    other = tmp_path / "Other.bvh"  # another skeleton: a joint renamed
    other.write_text(re.sub(r"JOINT Neck1\b", "JOINT Neck2", clip.read_text(), count=1))
    renamed = r"Other.bvh: its skeleton has joint \d+ is 'Neck2' where the model's is 'Neck1'"
    with pytest.raises(PipelineError, match=renamed) as e:
        finetune.user_clip_data(data, [other], cache=cache)
    assert "\n" not in str(e.value)


TINY_CLI = ["--hidden", 8, "--generator-hidden", 16, "--filters", 4, "--epochs", 1]


def test_jaxstyle_lpn_refuses_bad_clips_in_one_line(folders, tmp_path, capsys):
    root, clip, _ = folders
    argv = ["lpn", "--data", root, "--styles", "Neutral", "--run", tmp_path / "run", *TINY_CLI, "--quiet"]
    for extra, message in ((["--clip", clip, "--clip-range", 0, 1], "shorter than the trajectory window"),
                           (["--clip", clip, "--finetune-steps", 0], "--clip needs fine-tuning steps"),
                           (["--clip", tmp_path / "none.bvh"], "none.bvh: no such file"),
                           (["--clip-range", 0, 5], "--clip-range needs --clip files")):
        assert cli.main([str(a) for a in argv + extra]) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err


@pytest.mark.slow
def test_jaxstyle_lpn_clip(folders, tmp_path, capsys):
    root, clip, _ = folders
    run = tmp_path / "run"
    argv = ["lpn", "--data", root, "--styles", "Neutral", "--run", run, *TINY_CLI, "--quiet"]
    assert cli.main([str(a) for a in argv + ["--clip", clip, "--asymmetric", "--finetune-steps", 2,
                                              "--rates", 0.1, 0.3]]) == 0
    out = capsys.readouterr().out
    assert "new styles from your clips: Limping_FW" in out and "| Limping_FW | " in out and "chosen rates:" in out
    chosen = json.loads((run / "lpn" / "chosen_rates.json").read_text())
    assert list(chosen) == ["Limping_FW"] and chosen["Limping_FW"]["rate"] in (0.1, 0.3)
    assert (run / "lpn" / "generators" / "Limping_FW.npz").is_file()
    assert json.loads((run / "lpn" / "clips.json").read_text())["new"][0]["path"] == str(clip)


def test_train_lpn_style_data_of_clips_normalises_with_the_base(folders, model):
    _, clip, cache = folders
    data, m = model
    data = finetune.user_clip_data(data, [clip], cache=cache)  # mirrored: two clips, one style
    assert len(data.new.specs) == 2 and data.new.styles == ("Limping_FW",)
    new = styledata.style_data(data.new, data.skeleton, base=data.base)
    x_norm, _ = data.base.normalisers()
    np.testing.assert_allclose(new.x, x_norm.apply(data.new.inputs), rtol=1e-5, atol=1e-5)
