"""Characters from a trained 2022 model (:mod:`jaxstyle.mason2022.synthesis`,
:mod:`jaxstyle.output.synthesis` with the model's :class:`jaxstyle.control.lpn_controller.StyleNetModel`,
``jaxstyle synthesize --model lpn-film``): a tiny LPN-FiLM
trained in a fixture is reloaded from its run folder, drives characters along paths through the
library and the command line, and blends 2 and 3 styles."""

from __future__ import annotations

import csv
import dataclasses
import json

import jax
import numpy as np
import pytest

from jaxstyle.cli.main import main
from jaxstyle.control import paths
from jaxstyle.data import folders, procedural
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2022 import finetune, pipeline, styledata
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.nn import film_generator as film
from jaxstyle.output import metrics, quality, report, synthesis
from jaxstyle.output.drive import blend_character
from jaxstyle.output.synthesis import quality_table


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run folder as ``jaxstyle lpn`` leaves it: RUN/lpn with a tiny LPN-FiLM (1 epoch) trained on
    two procedural styles, and the files of a FiLM fine-tuning on a third style at two rates
    (:func:`jaxstyle.mason2022.finetune.write_finetune`; the generators are the trained one shifted
    by a different constant per rate, so the chosen rate's generator is told apart; the sweep
    itself is tested in test_pipeline_2022.py)."""
    root = procedural.write_dataset(tmp_path_factory.mktemp("data") / "procedural",
                                    styles=["Neutral", "Crouched", "Limping"], gaits=("FW",), seconds=8,
                                    progress=False)
    run = tmp_path_factory.mktemp("run")
    styles, new_styles = folders.split_styles(root, ["Limping"])
    data = pipeline.build_data(root, styles, new_styles, cache=run / "cache")
    config = pipeline.model_config(data.base, hidden=8, generator_hidden=16, filters=4)
    model = pipeline.train_model(data, config, run / "lpn", epochs=1, progress=False)
    gen = model.params["style"]["generator"]
    gens = jax.tree.map(lambda v: np.stack([np.stack([np.asarray(v) + 0.01, np.asarray(v) - 0.02])]), gen)
    after = {split: {"mse": np.full((1, 2), 0.5), "bll": np.full((1, 2), 0.01)} for split in finetune.SPLITS}
    new = styledata.style_data(data.new, data.skeleton, base=data.base)
    result = finetune.FinetuneResult(("Limping",), (0.1, 0.5), gens, 0, 0.0, {}, after, np.array([1]), new)
    finetune.write_finetune(result, run / "lpn")
    return run, model, data, result


@pytest.fixture(scope="module")
def loaded(run_dir):
    run, _, _, _ = run_dir
    return synthesis2022.load_model(run / "lpn", cache=run / "cache")


def _equal_trees(a, b):
    return jax.tree.structure(a) == jax.tree.structure(b) and all(
        np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b),
                                                                      strict=True))


def test_a_trained_model_reloads_from_its_folder_with_its_data(run_dir, loaded):
    _, model, data, _ = run_dir
    assert loaded.model.name == "LPN FiLM" and loaded.model.config == model.config and loaded.epochs == 1
    assert _equal_trees(loaded.model.params, model.params)
    assert loaded.model.data.styles == ("Crouched", "Neutral") and loaded.data.new.styles == ("Limping",)
    for a, b in zip(loaded.data.base.normalisers(), data.base.normalisers(), strict=True):
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.std, b.std)
    np.testing.assert_array_equal(loaded.model.data.clips, model.data.clips)
    assert loaded.data.skeleton.names == data.skeleton.names


def test_characters_use_the_style_film_vectors_and_the_finetuned_generator(run_dir, loaded):
    _, model, _, result = run_dir
    chars = synthesis2022.characters(loaded, styles=["Neutral"], new_styles=["Limping"])
    s = model.data.styles.index("Neutral")
    np.testing.assert_allclose(chars[0].conditioning, train_lpn.film_vectors(model.params, model.data)[s],
                               rtol=1e-6)
    # the new style: the mean FiLM vector of its training clips under its fine-tuned generator
    tuned = result.params(model, "Limping")
    vec = film.clip_films(tuned["style"]["generator"], result.data.clips[result.data.train_clips[0]])
    np.testing.assert_allclose(chars[1].conditioning, vec.mean(axis=0), rtol=1e-5, atol=1e-6)
    assert chars[1].title.startswith("Limping (fine-tuned, rate ")
    with pytest.raises(folders.PipelineError, match="unknown style 'Nope'"):
        synthesis2022.characters(loaded, styles=["Nope"])


def test_film_blends_are_the_weighted_sum_of_film_vectors(loaded):
    a, b, c = synthesis2022.characters(loaded, styles=["Neutral", "Crouched"], new_styles=["Limping"])
    model = loaded.character_model()
    one = blend_character(model, [a, b, c], [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(np.asarray(one.conditioning), np.asarray(a.conditioning))  # exactly the single style
    w = [0.2, 0.3, 0.5]
    mix = blend_character(model, [a, b, c], w)
    ref = sum(wi * np.asarray(x.conditioning, np.float64) for wi, x in zip(w, (a, b, c), strict=True))
    np.testing.assert_allclose(np.asarray(mix.conditioning), ref, rtol=1e-5, atol=1e-6)
    assert mix.title == "20% Neutral + 30% Crouched + 50% Limping" and mix.dataset is a.dataset
    with pytest.raises(ValueError, match="barycentric"):
        blend_character(model, [a, b], [0.7, 0.7])
    with pytest.raises(ValueError, match="2 or 3 styles"):
        blend_character(model, [a], [1.0])


def test_synthesize_drives_characters_and_blends_with_the_2018_metrics(loaded, tmp_path):
    a, b, c = synthesis2022.characters(loaded, styles=["Neutral", "Crouched"], new_styles=["Limping"])
    model = loaded.character_model()
    # 4 characters on one 1 s path: the shapes of the command-line test below (one compiled rollout)
    chars = [a, b, blend_character(model, [a, b, c], [1.0, 0.0, 0.0]), blend_character(model, [a, b], [0.5, 0.5])]
    out = synthesis.synthesize(model, chars, loaded.data.skeleton, tmp_path,
                               synthesis.SynthesisOptions(path_names=("straight",), seconds=1.0, gif=False))
    assert out.frames == 4 * 60 and len(out.rows) == 4 + 2  # + a real clip per style
    skeleton = loaded.data.skeleton
    assert "quality.csv" in [f.name for f in out.files]
    pos = {}
    for ch in chars:
        with np.load(tmp_path / "bvh" / f"{ch.label}_straight.npz") as z:
            pos[ch.title] = z["positions"]
            assert z["contacts"].shape == (60, 2) and z["phase"].shape == (60, 8)
        assert (tmp_path / "bvh" / f"{ch.label}_straight.bvh").is_file()
    np.testing.assert_array_equal(pos[chars[2].title], pos[a.title])  # weights (1, 0, 0): the single style exactly
    assert np.abs(pos[chars[3].title] - pos[a.title]).max() > 1e-3
    assert np.abs(pos[chars[3].title] - pos[b.title]).max() > 1e-3
    # the quality row: the same metrics functions on the skeleton's joints of the network's positions
    row = next(r for r in out.rows if r["style"] == a.title and r["path"] == "straight")
    upm = estimate_units_per_meter(skeleton)
    sig = paths.named("straight", 1.0, out.speeds[a.title], units_per_meter=upm, fps=skeleton.fps)
    q = metrics.motion_quality(pos[a.title][:, :skeleton.num_joints], skeleton, skeleton.fps, units_per_meter=upm,
                               path_Tx2=sig.positions)
    for k, v in q.as_row().items():
        np.testing.assert_allclose(row[k], v, rtol=1e-6, equal_nan=True, err_msg=k)
    assert np.isfinite(row["foot_skating_locked_m_s"]) and row["foot_lock"]
    with open(tmp_path / "quality.csv") as f:
        assert len(list(csv.DictReader(f))) == len(out.rows)
    assert quality_table(out.rows)[2].startswith(f"| {a.title} | straight{report.stalled_mark(row)} | ")
    assert row["not_stepping"] == bool(row["lifted_step_ratio"] < quality.STEP_RATIO)  # 1 s: next to no step
    # the style distance to the character's capture (jaxstyle.output.style; its numerics: test_style.py);
    # 1 s holds no whole stride, so the gait term and the total are NaN ("n/a"), the pose term is not
    assert "style_distance" in row and np.isfinite(row["style_pose_m"]) and row["style_pose_m"] > 0
    assert "phase_rate_ratio" in row
    assert quality_table(out.rows)[0].endswith("| style distance m (shows) |")


def test_cli_synthesize_model_lpn_film(run_dir, capsys):
    run, _, _, _ = run_dir
    args = ["synthesize", "--model", "lpn-film", "--run", str(run), "--paths", "straight", "--synth-seconds", "1",
            "--every", "20", "--quiet"]
    assert main(args + ["--base-styles", "Neutral", "Crouched", "--blend-weights", "0.2", "0.3", "0.5"]) == 0
    text = capsys.readouterr().out
    assert "synthesis with LPN FiLM (1 epochs" in text
    assert "| 20% Neutral + 30% Crouched + 50% Limping | straight" in text  # (a mark may follow)
    out = run / "synthesis" / "lpn-film"
    assert (out / "straight.gif").is_file() and (out / "quality.csv").is_file()
    assert (out / "bvh" / "Limping_straight.bvh").is_file()
    # one-line errors: a model of another kind, a missing folder, a bad blend
    assert main(["synthesize", "--model", "lpn-onehot", "--run", str(run), "--quiet"]) == 1
    assert "holds LPN FiLM (lpn-film)" in capsys.readouterr().err
    assert main(["synthesize", "--model", "lpn-film", "--run", str(run / "nothing"), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "no trained 2022 model in" in err and len(err.strip().splitlines()) == 1
    assert main(args + ["--blend-weights", "0.5", "0.6"]) == 1
    assert "barycentric" in capsys.readouterr().err


def test_a_new_style_that_failed_every_check_is_refused_unless_allowed(run_dir, tmp_path):
    """A new style marked in chosen_rates.json as failing the closed-loop check at every rate (as
    the clip sweep writes it) is refused with one line naming it and the figure; allowed, it is marked."""
    import shutil

    run, _, _, _ = run_dir
    folder = tmp_path / "lpn"
    shutil.copytree(run / "lpn", folder)
    path = folder / "chosen_rates.json"
    chosen = json.loads(path.read_text())
    chosen["Limping"].update(check_passed=False, failed=["bone error 0.412 > 0.1"])
    path.write_text(json.dumps(chosen))
    loaded = synthesis2022.load_model(folder, cache=run / "cache")
    with pytest.raises(folders.PipelineError) as e:
        synthesis2022.characters(loaded, new_styles=["Limping"])
    line = str(e.value)
    assert "\n" not in line and "new style Limping failed the closed-loop check at every rate" in line
    assert "bone error 0.412 > 0.1" in line and "--allow-failed" in line
    (char,) = synthesis2022.characters(loaded, new_styles=["Limping"], allow_failed=True)
    assert char.title.endswith("[FAILED CHECK]")


def test_the_style_check_walks_every_style_and_names_the_ones_not_stepping(loaded):
    """``jaxstyle lpn``'s closing check (:func:`jaxstyle.mason2022.synthesis.style_check`; the command's
    output: test_cli.py): the training styles and the fine-tuned new style walked along a straight
    line and measured by the quality benchmark, one table row each, and the styles whose rows say
    ``not_stepping`` named in the table's last line (a 1-epoch model: whatever it does, the line
    must agree with the rows)."""
    from jaxstyle.mason2022 import report as report2022

    rows = synthesis2022.style_check(loaded, ["Crouched", "Neutral"], ["Limping"], seconds=2.0)
    walked = [r for r in rows if r["path"] != "capture"]
    assert [(r["style"].split(" (")[0], r["kind"], r["path"]) for r in walked] == [
        ("Crouched", "base", "straight"), ("Neutral", "base", "straight"), ("Limping", "few-shot", "straight")]
    assert len(rows) == 6 and all(r["path"] == "capture" for r in rows[3:])
    assert all(r["not_stepping"] == bool(r["lifted_step_ratio"] < quality.STEP_RATIO) for r in walked)
    table = report2022.style_check_table(rows)
    assert [line.split(" | ")[0] for line in table[2:5]] == [f"| {r['style']}{report.stalled_mark(r)}"
                                                             for r in walked]
    named = [r["style"] for r in walked if r["not_stepping"]]
    assert table[-1] == (f"not stepping (lifted steps under 0.5 of the capture's, or diverged): {', '.join(named)}"
                         if named else "every style steps (lifted steps at least 0.5 of its capture's)")
    # a style said not stepping is named, whatever this model did
    forced = [{**r, "not_stepping": r["style"].startswith("Neutral")} if r["path"] != "capture" else r for r in rows]
    assert report2022.style_check_table(forced)[-1].endswith("or diverged): Neutral")
    blank = [{**r, "lifted_step_ratio": float("nan"), "not_stepping": None} for r in rows]  # e.g. a capture
    assert all(" | n/a | " in line for line in report2022.style_check_table(blank)[2:5])  # without lifted steps


def test_epoch_score_counts_styles_within_25_percent_then_those_not_stepping():
    """:func:`jaxstyle.mason2022.synthesis.epoch_score` on lifted-step ratios: within 25% is
    ``|r - 1| <= 0.25`` (0.75 and 1.25 count, 0.74 and 1.26 do not); not stepping is under
    :data:`jaxstyle.output.quality.STEP_RATIO`; NaN counts as neither."""
    assert synthesis2022.epoch_score({"a": 0.75, "b": 1.25, "c": 0.74, "d": 1.26, "e": float("nan")}) == (2, 0)
    assert synthesis2022.epoch_score({"a": 0.49, "b": 0.0, "c": 0.5, "d": 1.0}) == (1, -2)
    assert synthesis2022.epoch_score({}) == (0, 0)


def test_stepping_rates_take_the_lowest_validation_loss_among_rates_that_step_within_25_percent():
    """:func:`jaxstyle.mason2022.synthesis.stepping_rates`: per style the lowest validation loss among
    the rates whose lifted-step ratio is within 25% of 1 (0.75 and 1.25 count), else among those of
    at least :data:`jaxstyle.output.quality.STEP_RATIO`, else among all; a NaN ratio or loss never wins
    over a finite one."""
    nan = float("nan")
    val = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [nan, 2.0, 3.0], [1.0, 2.0, 3.0],
                    [3.0, 2.0, 1.0]])
    ratio = np.array([[0.4, 1.25, 1.0],    # within: rates 1 and 2; the lower loss: 1
                      [0.74, 0.6, 0.3],    # none within; stepping: 0 and 1; the lower loss: 0
                      [0.1, 0.2, nan],     # none steps: the lowest loss of all, 0
                      [1.0, 1.0, 0.2],     # within: 0 (its loss NaN) and 1: 1
                      [nan, 1.26, 0.75],   # within: 2 only
                      [0.49, 0.5, 0.0]])   # stepping: 1 only
    assert synthesis2022.stepping_rates(val, ratio).tolist() == [1, 0, 0, 1, 2, 1]


def test_the_rate_check_walks_every_style_and_rate_with_its_own_generator(run_dir, loaded, monkeypatch, tmp_path):
    """:func:`jaxstyle.mason2022.synthesis.rate_check` and ``choose_stepping_rates``: quality.run is
    replaced by one that checks it was given, for each (new style, rate), the FiLM vector of that
    rate's generator over the style's training clips, walked straight for the check's seconds, and
    returns set ratios; they come back in their (style, rate) cells, choose the rate, are written to
    ``chosen_rates.json`` and shown by the fine-tuning table."""
    from jaxstyle.mason2022 import report as report2022

    _, model, _, result = run_dir
    clips = result.data.clips[result.data.train_clips[0]]
    expected = {f"Limping (fine-tuned, rate {rate:g})": film.clip_films(
        jax.tree.map(lambda v, r=r: v[0, r], result.generators), clips).mean(axis=0)
        for r, rate in enumerate(result.rates)}
    given = {"Limping (fine-tuned, rate 0.1)": 0.3, "Limping (fine-tuned, rate 0.5)": 1.1}

    def run(character_model, subjects, skeleton, *, path_names, seconds):
        assert path_names == ("straight",) and seconds == synthesis2022.STYLE_CHECK_SECONDS
        assert [s.title for s in subjects] == list(expected) and {s.kind for s in subjects} == {"few-shot"}
        for s in subjects:
            np.testing.assert_allclose(s.conditioning, expected[s.title], rtol=1e-5, atol=1e-6)
        rows = [{"style": s.title, "path": "straight", "lifted_step_ratio": given[s.title]} for s in subjects]
        return quality.Measured(rows + [{"style": "Limping", "path": "capture"}], {})

    monkeypatch.setattr(quality, "run", run)
    ratios = synthesis2022.rate_check(loaded, result)
    np.testing.assert_array_equal(ratios, [[0.3, 1.1]])
    # the lower validation loss (rate 0.1) does not step; rate 0.5 steps within 25%
    losses = {split: {"mse": np.array([[0.2, 0.3]]), "bll": np.zeros((1, 2))} for split in finetune.SPLITS}
    before = {split: {"mse": np.array([0.4]), "bll": np.zeros(1)} for split in finetune.SPLITS}
    lossy = dataclasses.replace(result, before=before, after=losses, chosen=np.array([0]))
    chosen = synthesis2022.choose_stepping_rates(loaded, lossy)
    assert chosen.chosen.tolist() == [1] and chosen.chosen_rate("Limping") == 0.5
    np.testing.assert_array_equal(chosen.lifted_step_ratio, [[0.3, 1.1]])
    saved = json.loads(finetune.write_finetune(chosen, tmp_path)["chosen"].read_text())
    assert saved["Limping"]["rate_index"] == 1 and saved["Limping"]["lifted_step_ratio"] == {"0.1": 0.3, "0.5": 1.1}
    table = report2022.finetune_table(chosen)
    assert "| Limping | 0.30 | 1.10 (chosen) |" in table and table[-1].startswith(
        "\n(the validation rows choose the rate among the rates whose walk")


def test_the_epoch_chosen_by_the_closed_loop_is_recorded_loaded_and_dropped_by_further_training(
        run_dir, tmp_path, monkeypatch):
    """:func:`jaxstyle.mason2022.synthesis.choose_epoch` on a 3-epoch run: the closed-loop check is
    replaced by one that first checks it was given that epoch's own saved weights and then returns
    set ratios, so the rule is tested on known figures (the check itself: the test above). The
    epoch with the most styles within 25% wins over a later one with fewer; its weights come back,
    the choice is recorded, and ``load_model`` and a rerun of ``train_model`` load that epoch; a
    recorded choice is reused without driving; a record made for another number of epochs trained
    is stale (the last epoch again); a damaged record is refused in one line naming the file."""
    from jaxstyle.data.folders import PipelineError
    from jaxstyle.mason2022 import report as report2022

    run, model, data, _ = run_dir
    folder = tmp_path / "lpn"
    last = pipeline.train_model(data, model.config, folder, epochs=3, progress=False)
    saved = synthesis2022.train_config(json.loads((folder / "config.json").read_text())["train"])
    assert train_lpn.saved_epochs(folder, saved, model.data.styles) == [1, 2, 3]
    weights = {e: train_lpn.load(folder, saved, model.data.styles, epoch=e).params for e in (1, 2, 3)}
    assert _equal_trees(weights[3], last.params) and not _equal_trees(weights[2], weights[3])
    ratios = {1: {"Crouched": 1.0, "Neutral": 0.3}, 2: {"Crouched": 1.1, "Neutral": 0.8},
              3: {"Crouched": 0.9, "Neutral": 1.5}}  # scores (1, -1), (2, 0), (1, 0): epoch 2
    seen = []

    def check(candidate, styles, new_styles=(), *, seconds=None):
        assert _equal_trees(candidate.model.params, weights[candidate.epochs]) and list(styles) == ["Crouched",
                                                                                                     "Neutral"]
        seen.append(candidate.epochs)
        walked = [{"style": s, "path": "straight", "lifted_step_ratio": ratios[candidate.epochs][s]} for s in styles]
        return walked + [{"style": s, "path": "capture", "lifted_step_ratio": float("nan")} for s in styles]

    monkeypatch.setattr(synthesis2022, "style_check", check)
    choice = synthesis2022.choose_epoch(last, data, folder)
    assert seen == [1, 2, 3] and (choice.epoch, choice.trained_epochs) == (2, 3) and choice.ratios == ratios
    assert _equal_trees(choice.model.params, weights[2])
    assert pipeline.chosen_epoch(folder, 3) == 2 and pipeline.chosen_epoch(folder, 4) is None
    table = report2022.epoch_choice_table(choice)
    assert table[0] == "| epoch | Crouched | Neutral | within 25% | not stepping | |"
    assert table[2:] == ["| 1 | 1.00 | 0.30 | 1 | 1 |  |", "| 2 | 1.10 | 0.80 | 2 | 0 | chosen |",
                         "| 3 | 0.90 | 1.50 | 1 | 0 |  |"]
    # a tie goes to the later epoch; two epochs compared
    ratios[3], third = dict(ratios[2]), ratios[3]
    assert synthesis2022.choose_epoch(last, data, folder, epochs=2, reuse=False).epoch == 3
    ratios[3] = third
    assert synthesis2022.choose_epoch(last, data, folder, reuse=False).epoch == 2  # chosen again, recorded
    loaded = synthesis2022.load_model(folder, cache=run / "cache")
    assert loaded.epochs == 2 and _equal_trees(loaded.model.params, weights[2])
    assert (loaded.trained_epochs, loaded.epoch_text()) == (3, "epoch 2 of 3")
    assert _equal_trees(pipeline.train_model(data, model.config, folder, epochs=3, progress=False).params, weights[2])
    # the choice switched off (--choose-epoch 0): the last epoch, here and wherever the folder is loaded
    record = (folder / pipeline.CHOSEN_EPOCH_FILE).read_text()
    unchosen = pipeline.train_model(data, model.config, folder, epochs=3, progress=False, chosen=False)
    assert _equal_trees(unchosen.params, weights[3]) and not (folder / pipeline.CHOSEN_EPOCH_FILE).exists()
    reloaded = synthesis2022.load_model(folder, cache=run / "cache")
    assert reloaded.epochs == 3 and reloaded.epoch_text() == "3 epochs"
    assert _equal_trees(reloaded.model.params, weights[3])
    (folder / pipeline.CHOSEN_EPOCH_FILE).write_text(record)
    seen.clear()
    again = synthesis2022.choose_epoch(last, data, folder)  # recorded: read back, nothing driven
    assert seen == [] and again.epoch == 2 and _equal_trees(again.model.params, weights[2])
    assert again.ratios == ratios
    assert synthesis2022.choose_epoch(last, data, folder, epochs=1).ratios == {}  # nothing to choose from
    # a record of another training (a run trained on within its budget, pipeline.train_for) is stale
    (folder / pipeline.CHOSEN_EPOCH_FILE).write_text('{"epoch": 2, "trained_epochs": 5}')
    reloaded = synthesis2022.load_model(folder, cache=run / "cache")
    assert reloaded.epochs == 3 and _equal_trees(reloaded.model.params, weights[3])
    (folder / pipeline.CHOSEN_EPOCH_FILE).write_text("{not json")
    with pytest.raises(PipelineError, match=r"chosen_epoch.json: not a chosen-epoch record") as e:
        synthesis2022.load_model(folder, cache=run / "cache")
    assert "\n" not in str(e.value)


def test_a_bfloat16_run_reloads_with_its_compute_dtype(run_dir, tmp_path):
    """A run trained with bfloat16 products (``jaxstyle lpn --bf16``) records ``"compute_dtype":
    "bfloat16"`` in ``config.json`` (its weights stay float32); ``load_model`` opens its checkpoints
    with that config and gives the trained weights. The fixture's folder with that line added stands
    for such a run (no second training)."""
    import shutil

    run, model, _, _ = run_dir
    shutil.copytree(run / "lpn", tmp_path / "lpn")
    saved = json.loads((tmp_path / "lpn" / "config.json").read_text())
    (tmp_path / "lpn" / "config.json").write_text(json.dumps({**saved, "compute_dtype": "bfloat16"}))
    loaded = synthesis2022.load_model(tmp_path / "lpn", cache=run / "cache")
    assert loaded.epochs == 1 and _equal_trees(loaded.model.params, model.params)
