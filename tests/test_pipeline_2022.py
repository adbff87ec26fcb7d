"""The 2022 pipeline (:mod:`jaxstyle.mason2022.pipeline`) on tiny procedural data, the shared style
folder functions (:mod:`jaxstyle.data.folders`) and the command modules' structure."""

from __future__ import annotations

import json

import numpy as np
import pytest

from jaxstyle.data import folders, procedural
from jaxstyle.mason2018 import pipeline as pipeline2018
from jaxstyle.mason2022 import pipeline


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = procedural.write_dataset(tmp_path_factory.mktemp("data") / "procedural", styles=["Neutral", "Limping"],
                                    gaits=("FW",), seconds=10, progress=False)
    return root, tmp_path_factory.mktemp("cache")


def test_choose_rates_takes_the_lowest_finite_loss_else_the_first():
    loss = np.array([[0.3, 0.1, 0.2], [np.nan, np.nan, np.nan], [0.5, np.nan, 0.4], [0.2, 0.2, 0.3]])
    assert pipeline.choose_rates(loss).tolist() == [1, 0, 2, 0]


def test_the_2018_pipeline_reexports_the_folder_functions():
    for name in ("style_root", "split_styles", "clip_specs", "available_styles", "PipelineError", "PAPER_FEWSHOT"):
        assert getattr(pipeline2018, name) is getattr(folders, name)


def test_build_train_finetune_select_report(tiny, tmp_path):
    root, cache = tiny
    styles, new_styles = folders.split_styles(root)
    assert (styles, new_styles) == (("Neutral",), ("Limping",))
    data = pipeline.build_data(root, styles, new_styles, cache=cache)
    config = pipeline.model_config(data.base, hidden=8, generator_hidden=16, filters=4)
    assert config.input_size == data.base.inputs.shape[1] and config.generator.film_size == 32
    model = pipeline.train_model(data, config, tmp_path / "lpn", epochs=1, progress=False)
    assert pipeline.losses_table(model.data.styles, pipeline.model_losses(model))[2].startswith("| Neutral | ")
    result = pipeline.finetune_sweep(model, data, rates=(0.1, 0.5), steps=2, progress=False)
    assert result.styles == ("Limping",) and result.rates == (0.1, 0.5) and result.steps == 2
    assert result.after["test"]["mse"].shape == (1, 2) and np.isfinite(result.after["test"]["mse"]).all()
    assert result.chosen_rate("Limping") in (0.1, 0.5)
    lines = pipeline.finetune_table(result)
    assert lines[0].startswith("| new style | test MSE before | after @ 0.1 | after @ 0.5 | chosen rate |")
    assert any("(chosen)" in line for line in lines)
    paths = pipeline.write_finetune(result, tmp_path / "out")
    chosen = json.loads(paths["chosen"].read_text())
    assert chosen["Limping"]["rate"] == result.chosen_rate("Limping")
    with np.load(paths["generators"]) as z:
        assert all(z[k].shape[:2] == (1, 2) for k in z.files)
    assert pipeline.film_figure(model, result, tmp_path / "out" / "figure11.png").is_file()


def test_model_config_refuses_the_pfnn_backbone(tiny):
    root, cache = tiny
    data = pipeline.build_data(root, ("Neutral",), cache=cache)
    assert data.new is None
    with pytest.raises(folders.PipelineError, match="global phase"):
        pipeline.model_config(data.base, "PFNN FiLM")


def test_every_command_module_is_a_thin_parser_and_run():
    from jaxstyle.cli.main import COMMANDS, build_parser  # (jaxstyle.cli.main itself is the function)

    for command in COMMANDS:
        assert command.NAME and command.HELP and command.DOC
        assert hasattr(command, "ACTIONS") or (callable(command.add_arguments) and callable(command.run))
    parser, subs = build_parser()
    assert {"demo", "data generate", "data fetch", "data prepare", "train-base", "sweep", "lpn", "synthesize",
            "render", "bench"} <= set(subs)
