"""Guards on datasets, training and checkpoints (docs/bad_input.md, "Datasets, training and
checkpoints"): absurd or non-finite feature rows, mixed skeletons and dropped styles are refused
with errors naming the files; NaN is never trained into a checkpoint nor written into JSON; a
damaged newest checkpoint step falls back to the newest good one, and a resumed run says so."""

from __future__ import annotations

import json
import logging
import shutil
import warnings
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.data import clips as C
from jaxstyle.data import datasets as D
from jaxstyle.train import defaults
from jaxstyle.train.checkpoint import Checkpointer
from tests.toy_fit import toy_fit


def _strict_json(text: str):
    def refuse(token):
        raise ValueError(f"non-strict JSON token {token}")

    return json.loads(text, parse_constant=refuse)


# --- datasets ------------------------------------------------------------------------------------

def _xia_copy(mocap, folder: Path, name: str = "neutral_01_000.bvh", edit=None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    text = (mocap / "xia" / name).read_text()
    if edit is not None:
        head, motion = text.split("MOTION", 1)
        lines = motion.splitlines()  # lines[0] is empty, [1] Frames:, [2] Frame Time:, then frames
        edit(lines)
        text = head + "MOTION" + "\n".join(lines) + "\n"
    (folder / name).write_text(text)
    return folder / name


def test_absurd_root_value_is_refused_naming_the_file_and_frame(mocap, tmp_path):
    def absurd(lines):
        for i in range(3 + 197, 3 + 201):  # file frames 197..200: root X = 1e300 (a finite number)
            values = lines[i].split()
            values[0] = "1e300"
            lines[i] = " ".join(values)

    path = _xia_copy(mocap, tmp_path / "clips", edit=absurd)
    specs = C.specs_xia(path.parent, mirror=False)
    for build in (D.build_pfnn_dataset, D.build_lpn_dataset):
        # refused by the reader (line of the file) or by the builder (frame of the file)
        with pytest.raises(js.MotionDataError, match=r"(frame 197 .*Hips|row 198 ).*1e\+?300") as info:
            build(specs, cache_dir=tmp_path / "cache")
        assert info.value.path == str(path) and str(path) in str(info.value)
    assert not list((tmp_path / "cache").glob("*.npz"))  # nothing cached
    # the builder's own guard, whatever the reader lets through
    spec = C.ClipSpec(str(path), "neutral", start=10)
    motion = js.read_bvh(mocap / "xia/neutral_01_000.bvh").frames(10, 300)
    positions = motion.local_positions.copy()
    positions[187:191, 0, 0] = 1e300
    with pytest.raises(js.MotionDataError, match=r"neutral_01_000.bvh: frame 197 \(0-based\) has joint positions "
                                                 r"of 'Hips' beyond 1e\+06 \(1e\+300; 4 such frames\)"):
        D._check_motion(spec, motion.replace(local_positions=positions))
    positions[187, 0, 0] = np.nan
    with pytest.raises(js.MotionDataError, match=r"frame 197 .*not finite"):
        D._check_motion(spec, motion.replace(local_positions=positions))
    D._check_motion(spec, motion)  # a good clip passes


def test_non_finite_feature_rows_are_refused_naming_the_file_and_frame():
    spec = C.ClipSpec("clip.bvh", "walk", start=100)
    rows = np.zeros((5, 4))
    rows[3, 2] = np.nan
    with pytest.raises(js.MotionDataError, match=r"clip.bvh: the row of frame 106 .*not finite"):
        D._check_rows(spec, 60.0, 120.0, [("inputs", rows)], lambda name, r: r)  # 120 fps file: frame 2 * 3
    rows[3, 2] = 5e7
    with pytest.raises(js.MotionDataError, match=r"beyond 1e\+06"):
        D._check_rows(spec, 60.0, 60.0, [("inputs", rows)], lambda name, r: r)


def test_a_cache_holding_nan_is_built_again(mocap, tmp_path):
    specs = C.specs_xia(_xia_copy(mocap, tmp_path / "clips").parent, mirror=False)
    good = D.build_pfnn_dataset(specs, cache_dir=tmp_path / "cache")
    (path,) = (tmp_path / "cache").glob("pfnn-*.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["inputs"] = arrays["inputs"].copy()
    arrays["inputs"][0, 0] = np.nan  # what an older jaxstyle cached from a damaged file
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    again = D.build_pfnn_dataset(specs, cache_dir=tmp_path / "cache")
    assert np.isfinite(again.inputs).all()
    np.testing.assert_array_equal(again.inputs, good.inputs)


def test_mixed_skeletons_are_refused_naming_both_files(mocap):
    xia = C.ClipSpec(str(mocap / "xia/neutral_01_000.bvh"), "neutral")
    other = C.ClipSpec(str(mocap / "100style/Neutral/Neutral_FW.bvh"), "Neutral", 0, 900)
    joints = (len(js.read_bvh(xia.path).names), len(js.read_bvh(other.path).names))
    assert joints[0] != joints[1]
    with pytest.raises(js.MotionDataError) as info:
        D.build_pfnn_dataset([xia, other])
    message = str(info.value)
    assert xia.path in message and other.path in message, message
    assert f"{joints[1]} joints, but {xia.path} has {joints[0]}" in message, message


def test_a_short_clip_warns_and_a_style_left_without_clips_is_an_error(mocap, caplog):
    long_clip = C.ClipSpec(str(mocap / "xia/neutral_01_000.bvh"), "neutral")
    short = C.ClipSpec(str(mocap / "xia/angry_13_000.bvh"), "angry")  # 70 frames at 60 fps
    short_neutral = C.ClipSpec(str(mocap / "xia/angry_13_000.bvh"), "neutral")
    # the style's only clip is too short: an error naming the style, the clip, its length and the minimum
    with pytest.raises(js.MotionDataError, match=r"'angry'.*angry_13_000.bvh \(70 frames, needs 112\)"), \
            pytest.warns(UserWarning, match="skipped"):
        D.build_pfnn_dataset([long_clip, short], skip_short=True)
    # a style keeps another clip: a warning (and a log line, which silenced warnings do not hide)
    with pytest.warns(UserWarning, match=r"angry_13_000.bvh: .*70 frames at 60 fps.*at least 112 frames"):
        ds = D.build_pfnn_dataset([long_clip, short_neutral], skip_short=True)
    assert ds.styles == ("neutral",) and len(ds.specs) == 1
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="jaxstyle.data.datasets"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # as the pipelines do
        D.build_pfnn_dataset([long_clip, short_neutral], skip_short=True)
    assert any("angry_13_000.bvh" in r.getMessage() and "skipped" in r.getMessage() for r in caplog.records)


# --- training and checkpoints -------------------------------------------------------------------

def _fit(directory, poison_epoch: int | None = None, **kw):
    """The toy run of tests/toy_fit.py (3 epochs); from ``poison_epoch`` on, its weights turn NaN
    while the reported loss stays finite."""
    return toy_fit(directory, {"run": "toy"}, poison_epoch=poison_epoch, **kw)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A finished 3-epoch run (steps 1, 2, 3) and its final state."""
    directory = tmp_path_factory.mktemp("guards") / "run"
    state = _fit(directory, say=None)
    assert sorted(int(p.name) for p in (directory / "steps").iterdir()) == [1, 2, 3]
    return directory, state


def _truncate_data(step: Path):
    files = [p for p in step.rglob("*") if p.is_file() and p.parent.name == "d"]
    assert files
    for p in files:
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 3])


def _empty_metadata(step: Path):
    (step / "default" / "_METADATA").write_text("")


def _empty_folder(step: Path):
    shutil.rmtree(step)
    step.mkdir()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # orbax's loop, on a damaged file
@pytest.mark.filterwarnings("ignore:coroutine .* was never awaited:RuntimeWarning")
@pytest.mark.parametrize("damage", [_truncate_data, _empty_metadata, _empty_folder])
def test_a_damaged_latest_step_falls_back_and_the_resumed_run_says_so(trained, tmp_path, damage):
    source, finished = trained
    directory = tmp_path / "run"
    shutil.copytree(source, directory)
    damage(directory / "steps" / "3")
    said = []
    expected = rf"checkpoint step 3 in {directory / 'steps'} is damaged \(.+\); using step 2"
    with pytest.warns(UserWarning, match=expected):
        resumed = _fit(directory, say=said.append)
    assert said == [f"resumed from step 2 in {directory / 'steps'} (epoch 2 done)"]
    assert int(resumed.epoch) == 3
    np.testing.assert_allclose(resumed.w, finished.w, rtol=1e-6)  # epoch 3 trained again
    assert len(list((directory / "damaged").iterdir())) == 1  # the damaged step kept aside
    ckpt = Checkpointer(directory, {"run": "toy"})
    assert ckpt.all_steps() == [1, 2, 3] and int(ckpt.restore(resumed).epoch) == 3
    ckpt.close()


def test_no_good_step_is_one_error_naming_the_folder(trained, tmp_path):
    source, finished = trained
    directory = tmp_path / "run"
    shutil.copytree(source, directory)
    _truncate_data(directory / "steps" / "3")
    _empty_metadata(directory / "steps" / "2")
    _empty_folder(directory / "steps" / "1")
    with pytest.raises(js.JaxstyleError, match=rf"no usable checkpoint in {directory / 'steps'}: .*step 3: .*"
                                               r"step 2: .*step 1: the step folder is empty"):
        _fit(directory, say=None)


def test_a_resumed_run_says_so(trained, tmp_path):
    directory = tmp_path / "run"
    _fit(directory, stop_after_epochs=1, say=None)
    said = []
    _fit(directory, say=said.append)
    assert said == [f"resumed from step 1 in {directory / 'steps'} (epoch 1 done)"]


def test_nan_parameters_are_never_saved(tmp_path):
    ckpt = Checkpointer(tmp_path / "ck", {"run": "nan"})
    with pytest.raises(FloatingPointError, match=r"refusing to save checkpoint step 1 .*w hold NaN"):
        ckpt.save(1, {"w": jnp.array([1.0, jnp.nan]), "epoch": jnp.asarray(1)})
    assert ckpt.latest_step() is None
    ckpt.close()
    # training: finite losses but NaN weights from epoch 2 on stop the run before saving epoch 2
    directory = tmp_path / "run"
    with pytest.raises(FloatingPointError, match=r"epoch 2: the state's .*\bw\b.* hold NaN.*last checkpoint kept is "
                                                 r"step 1") as info:
        _fit(directory, poison_epoch=1, say=None)
    assert isinstance(info.value, js.JaxstyleError)
    assert sorted(int(p.name) for p in (directory / "steps").iterdir()) == [1]
    with open(directory / "log.csv") as f:
        assert [line.split(",")[0] for line in f.read().split()] == ["epoch", "1"]


# --- JSON ----------------------------------------------------------------------------------------

def test_chosen_rates_json_is_strict_with_null_for_a_missing_loss(tmp_path):
    from jaxstyle.mason2018 import fewshot, selection, sweep_files

    S, R = 2, 2
    result = selection.SweepResult(
        styles=("a", "b"), rates=(0.0, 0.1), adapters={"u": np.zeros((S, R, 3), np.float32)},
        train_loss=np.array([[0.5, np.nan], [0.4, 0.3]]), validation_loss=np.array([[np.nan, np.nan], [0.2, 0.1]]),
        rollout={k: np.ones((S, R)) for k in defaults.ROLLOUT_FIELDS}, reference={},
        chosen=np.array([0, 1]), chosen_passed=np.array([False, True]), train_rows=(3, 4), validation_rows=(0, 2),
        seconds={"sweep": float("nan")})
    paths = sweep_files.write_report(result, tmp_path, fewshot.SweepConfig())
    chosen = _strict_json(paths["chosen"].read_text())
    assert chosen["a"]["validation_loss"] is None and chosen["b"]["validation_loss"] == pytest.approx(0.1)


def test_json_text_writes_null_for_nan_and_inf():
    from jaxstyle.train.checkpoint import json_text

    text = json_text({"x": float("nan"), "y": [np.float32(np.inf), np.float64(1.5), np.int64(2)], "z": (True,)})
    assert _strict_json(text) == {"x": None, "y": [None, 1.5, 2], "z": [True]}
