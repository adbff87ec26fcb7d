"""The 2022 pipeline (:mod:`jaxstyle.mason2022.pipeline`) on tiny procedural data, the shared style
folder functions (:mod:`jaxstyle.data.folders`) and the command modules' structure."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from jaxstyle.data import folders, procedural
from jaxstyle.mason2022 import finetune, pipeline, report
from jaxstyle.output import check as check_lib


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = procedural.write_dataset(tmp_path_factory.mktemp("data") / "procedural", styles=["Neutral", "Limping"],
                                    gaits=("FW",), seconds=10, progress=False)
    return root, tmp_path_factory.mktemp("cache")


def test_choose_rates_takes_the_lowest_finite_loss_else_the_first():
    loss = np.array([[0.3, 0.1, 0.2], [np.nan, np.nan, np.nan], [0.5, np.nan, 0.4], [0.2, 0.2, 0.3]])
    assert check_lib.choose_rates(loss)[0].tolist() == [1, 0, 2, 0]


@pytest.mark.slow  # the default run goes the same way through `jaxstyle lpn` (tests/test_cli.py), files checked
def test_build_train_finetune_select_report(tiny, tmp_path):
    root, cache = tiny
    styles, new_styles = folders.split_styles(root)
    assert (styles, new_styles) == (("Neutral",), ("Limping",))
    data = pipeline.build_data(root, styles, new_styles, cache=cache)
    config = pipeline.model_config(data.base, hidden=8, generator_hidden=16, filters=4)
    assert config.input_size == data.base.inputs.shape[1] and config.generator.film_size == 32
    model = pipeline.train_model(data, config, tmp_path / "lpn", epochs=1, progress=False)
    assert report.losses_table(model.data.styles, pipeline.model_losses(model))[2].startswith("| Neutral | ")
    result = finetune.generator_sweep(model, data, rates=(0.1, 0.5), steps=2, progress=False)
    assert result.styles == ("Limping",) and result.rates == (0.1, 0.5) and result.steps == 2
    assert result.after["test"]["mse"].shape == (1, 2) and np.isfinite(result.after["test"]["mse"]).all()
    assert result.chosen_rate("Limping") in (0.1, 0.5)
    lines = report.finetune_table(result)
    assert lines[0].startswith("| new style | test MSE before | after @ 0.1 | after @ 0.5 | chosen rate |")
    assert any("(chosen)" in line for line in lines)
    paths = finetune.write_finetune(result, tmp_path / "out")
    chosen = json.loads(paths["chosen"].read_text())
    assert chosen["Limping"]["rate"] == result.chosen_rate("Limping")
    with np.load(paths["generators"]) as z:
        assert all(z[k].shape[:2] == (1, 2) for k in z.files)
    assert report.film_figure(model, result, tmp_path / "out" / "figure11.png").is_file()


# all three slow (17-40 s each): the default run checks the PFNN gate is the labeller's global phase
# (tests/test_lpn.py, tests/test_lpn_features.py) and the PFNN models' gradients (tests/test_lpn.py)
@pytest.mark.parametrize("name", [pytest.param("PFNN One-hot", marks=pytest.mark.slow),
                                  pytest.param("PFNN Resad", marks=pytest.mark.slow),
                                  pytest.param("PFNN FiLM", marks=pytest.mark.slow)])
def test_the_pfnn_backbones_train_on_the_global_phase_within_a_budget(tiny, tmp_path, name):
    """Table 2's PFNN-backbone models train on the LPN rows, gated by each row's global phase;
    a zero budget still gives one epoch, and a second call with a budget continues the run."""
    root, cache = tiny
    data = pipeline.build_data(root, ("Neutral",), cache=cache)
    assert data.new is None
    config = pipeline.model_config(data.base, name, hidden=8, generator_hidden=16, filters=4)
    assert config.backbone == "pfnn" and config.output_size == data.base.outputs.shape[1]
    run = pipeline.train_for(data, config, tmp_path / "m", pipeline.Budget(0.0, max_epochs=2), name=name,
                             progress=False)
    assert (run.epochs, run.stopped) == (1, "budget")
    np.testing.assert_array_equal(run.model.data.gate, data.base.global_phase[:, None])
    losses = pipeline.model_losses(run.model)
    assert np.isfinite(losses["mse"]).all() and np.isfinite(losses["bll"]).all()
    again = pipeline.train_for(data, config, tmp_path / "m", pipeline.Budget(1e6, max_epochs=2), name=name,
                               progress=False)
    assert (again.epochs, again.stopped) == (2, "max epochs")
    log = pipeline.read_log(tmp_path / "m")
    assert log["epoch"].tolist() == [1, 2] and np.isfinite(log["val_mse"]).all()
    table = report.budget_table({name: again}, {name: log})
    assert table[2].startswith(f"| {name} | 2 | max epochs | ")
    assert report.curves_figure({name: log}, tmp_path / "curves.png").is_file()


def test_model_config_refuses_a_dataset_without_global_phase(tiny):
    root, cache = tiny
    data = pipeline.build_data(root, ("Neutral",), cache=cache)
    stale = dataclasses.replace(data.base, global_phase=np.zeros(0, np.float32))  # an old cache
    with pytest.raises(folders.PipelineError, match="global phase"):
        pipeline.model_config(stale, "PFNN FiLM")
    assert pipeline.model_config(stale, "LPN FiLM").backbone == "lpn"  # the others do not need it


def test_flattened_and_the_paper_ordering_lines():
    assert not pipeline.flattened([1.0, 0.5, 0.4])  # too few epochs
    assert not pipeline.flattened([1.0, 0.5, 0.45, 0.40, 0.35])
    assert pipeline.flattened([1.0, 0.5, 0.499, 0.498, 0.497])
    assert pipeline.flattened([1.0, 0.5, 0.6, 0.7, 0.8])  # rising: flattened (and worse)
    assert not pipeline.flattened([1.0, 0.5, 0.6, 0.7, 0.3])
    r = {n: {"mse": np.array([m, m]), "bll": np.array([0.0, 0.0])}
         for n, m in (("LPN FiLM", 0.1), ("PFNN FiLM", 0.2), ("LPN One-hot", 0.15), ("PFNN Resad", 0.3),
                      ("LPN Resad", 0.25))}
    lines = report.ordering_lines(r)
    assert lines[0].startswith("ranked by test MSE + BLL (lowest first): LPN FiLM 0.1000, LPN One-hot 0.1500")
    assert "does not hold (worst FiLM PFNN FiLM 0.2000, best other LPN One-hot 0.1500)" in lines[1]
    assert "PFNN Resad below LPN Resad: does not hold (0.3000 vs 0.2500)" in lines[2]
    r["PFNN FiLM"] = {"mse": np.array([0.12]), "bll": np.array([0.0])}
    assert ": holds" in report.ordering_lines(r)[1]


def test_every_command_module_is_a_thin_parser_and_run():
    from jaxstyle.cli.main import COMMANDS, build_parser  # (jaxstyle.cli.main itself is the function)

    for command in COMMANDS:
        assert command.NAME and command.HELP and command.DOC
        assert hasattr(command, "ACTIONS") or (callable(command.add_arguments) and callable(command.run))
    parser, subs = build_parser()
    assert {"demo", "data generate", "data fetch", "data prepare", "train-base", "sweep", "lpn", "synthesize",
            "render", "bench"} <= set(subs)


def _row(model, style, path, steps, skating, contact, distance=1.0, shows=None, stalled=False, finite=True,
         not_stepping=False):
    return {"model": model, "style": style, "path": path, "steps_per_s": steps, "foot_skating_m_s": skating,
            "contact_fraction": contact, "style_distance": distance, "wrist_range_ratio": 0.5, "style_shows": shows,
            "phases_stalled": stalled, "finite": finite, "not_stepping": not_stepping}


def test_closed_loop_figures_tell_stepping_from_gliding():
    caps = [_row(m, s, "capture", 2.0, 0.1, 0.6) for m in ("LPN FiLM", "PFNN One-hot") for s in ("Drunk", "Angry")]
    rows = caps + [
        _row("LPN FiLM", "Drunk", "straight", 2.2, 0.2, 0.7, 0.3, shows=True),     # steps, 2x skating
        _row("LPN FiLM", "Angry", "straight", 0.2, 0.9, 0.99, 2.0, shows=False, stalled=True,
             not_stepping=True),  # glides
        _row("LPN FiLM", "Angry", "circle", np.nan, np.nan, np.nan, finite=False, not_stepping=True),  # left out
        _row("PFNN One-hot", "Drunk", "straight", 1.4, 0.4, 0.8, 0.5, shows=True),  # 0.7x: not within 25%
        _row("PFNN One-hot", "Angry", "straight", 2.4, 0.5, 0.96, 0.7, shows=True, not_stepping=True)]  # 1.2x, 96%
    for r, ratio in zip(rows[4:6], (1.0, 0.1), strict=True):  # the LPN's local phases: one stalled
        r["phase_rate_ratio"] = ratio
    for r in rows:  # lifted steps: the captures' 2.0 a second, Drunk's 2.2 onsets only 1.0 lifted (a slide)
        r["lifted_steps_per_s"] = {2.2: 1.0}.get(r["steps_per_s"], r["steps_per_s"])
    f = report.closed_loop_figures(rows)
    lpn, pfnn = f["LPN FiLM"], f["PFNN One-hot"]
    assert lpn["phase_rate_ratio"] == pytest.approx(0.55) and np.isnan(pfnn["phase_rate_ratio"])  # none: NaN
    assert (lpn["rows"], lpn["diverged"], lpn["stepping"], lpn["gliding"], lpn["stalled"]) == (3, 1, 1, 1, 1)
    assert (pfnn["rows"], pfnn["stepping"], pfnn["gliding"], pfnn["stalled"]) == (2, 1, 1, 0)
    assert (lpn["not_stepping"], pfnn["not_stepping"]) == (1, 1)  # the diverged row's flag is not counted
    assert (lpn["lifted_stepping"], pfnn["lifted_stepping"]) == (0, 1)
    np.testing.assert_allclose([lpn["steps_ratio"], lpn["skating_ratio"], lpn["style_distance"]],
                               [np.median([1.1, 0.1]), np.median([2.0, 9.0]), np.median([0.3, 2.0])])
    np.testing.assert_allclose([pfnn["steps_ratio"], pfnn["skating_ratio"]], [np.median([0.7, 1.2]), 4.5])
    assert (lpn["shows"], lpn["styled"], pfnn["shows"], pfnn["styled"]) == (1, 2, 2, 2)
    table = report.closed_loop_table(f, {"LPN FiLM": {"mse": np.array([0.1]), "bll": np.array([0.01])}})
    assert table[2].startswith("| LPN FiLM | 0.1100 | 1, 0 / 2 | 0.60 | 1 / 2 | 1 / 2 | 1 / 2 | 5.5 | 1.15 | 1 / 2 |"
                               " 0.50 | 1 / 3 |")
    assert table[3].startswith("| PFNN One-hot | - | 1, 1 / 2 |")
    lines = report.closed_loop_ordering_lines(f)
    assert lines[0] == "LPN FiLM most rows stepping within 25% of the capture: holds (LPN FiLM 1)"  # a tie holds
    assert lines[1] == ("LPN FiLM lowest median raw skating / capture: does not hold (LPN FiLM 5.50, best PFNN One-hot "
                        "4.50)")
    assert lines[2] == "LPN FiLM lowest median style distance: does not hold (LPN FiLM 1.15, best PFNN One-hot 0.60)"
    assert lines[3].startswith("every FiLM model's median style distance below every one-hot / adapter model's: "
                               "does not hold (worst FiLM LPN FiLM 1.15")
    assert report.closed_loop_ordering_lines({"LPN FiLM": lpn}) == []  # nothing to compare with


@pytest.mark.slow  # 2 tiny models, about 40 s
def test_train_models_trains_each_in_its_share_and_resumes(tiny, tmp_path):
    import time

    root, cache = tiny
    data = pipeline.build_data(root, ("Neutral",), cache=cache)
    seen = []
    names = ("LPN One-hot", "LPN FiLM")
    configs = {name: pipeline.model_config(data.base, name, hidden=8, generator_hidden=16, filters=4)
               for name in names}
    done = pipeline.train_models(data, configs, tmp_path,
                                 pipeline.SharedBudget(time.perf_counter(), jobs_after=1, max_epochs=2),
                                 progress=False, after_each=lambda name, d: seen.append((name, tuple(d.runs))))
    assert seen == [("LPN One-hot", ("LPN One-hot",)), ("LPN FiLM", names)]  # a partial report after each
    assert [(r.epochs, r.stopped) for r in done.runs.values()] == [(1, "budget"), (1, "budget")]  # no time: 1 epoch
    assert all(np.isfinite(done.results[n]["mse"]).all() and len(done.logs[n]["epoch"]) == 1 for n in names)
    assert report.model_line("LPN FiLM", done).startswith("LPN FiLM: 1 epochs (budget) in ")
    again = pipeline.train_models(data, configs, tmp_path,
                                  pipeline.SharedBudget(time.perf_counter() + 1e6, max_epochs=2), progress=False)
    assert [(r.epochs, r.stopped) for r in again.runs.values()] == [(2, "max epochs"), (2, "max epochs")]
