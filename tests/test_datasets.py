"""Dataset builders over the shared sample: layouts, splits, statistics, cache, bad input."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.data import clips as C
from jaxstyle.data import datasets as D
from jaxstyle.data.batching import balanced_batches
from jaxstyle.data.normalise import fit_normaliser


def test_specs_100style_cuts_and_mirrors_symmetric_styles(mocap, tmp_path):
    specs = C.specs_100style(mocap / "100style")
    gaits = {(s.style, s.gait) for s in specs}
    assert ("Angry", "FW") in gaits and ("Neutral", "TR1") in gaits
    assert len(gaits) == len(list((mocap / "100style").glob("*/*.bvh")))  # every file has cuts
    assert all(sum(s.mirror for s in specs if (s.style, s.gait) == g) == 1 for g in gaits)  # all symmetric
    angry_fw = next(s for s in specs if (s.style, s.gait, s.mirror) == ("Angry", "FW", False))
    assert (angry_fw.start, angry_fw.stop) == (569, 4407)  # Frame_Cuts.csv
    neutral = next(s for s in specs if (s.style, s.gait) == ("Neutral", "FW"))
    assert D.load_clip(neutral).num_frames == 1200 - neutral.start  # stop beyond the trimmed take: clipped
    # an asymmetric style is not mirrored
    root = tmp_path / "100style"
    root.mkdir()
    (root / "Angry").symlink_to(mocap / "100style/Angry")
    shutil.copy(mocap / "100style/Frame_Cuts.csv", root)
    text = (mocap / "100style/Dataset_List.csv").read_text(encoding="utf-8-sig")
    angry = next(line for line in text.splitlines() if line.startswith("Angry,"))
    (root / "Dataset_List.csv").write_text(text.replace(angry, angry.replace(",Yes,", ",No,", 1)))
    assert not any(s.mirror for s in C.specs_100style(root))


def test_lpn_dataset_layout_split_stats_and_cache(mocap, tmp_path):
    specs = [s for s in C.specs_100style(mocap / "100style", styles=["Neutral", "Rushed"]) if s.gait in ("FW", "ID")]
    ds = D.build_lpn_dataset(specs, cache_dir=tmp_path)
    assert ds.inputs.shape[1:] == (348,) and ds.outputs.shape[1:] == (342,) and ds.phases.shape[1:] == (8,)
    assert ds.clips.shape[1:] == (240, 300) and len(ds.clip_style) == len(ds.clips)
    assert ds.styles == ("Neutral", "Rushed") and ds.inputs.dtype == np.float32
    # splits: per clip, three contiguous blocks; a clip and its mirror share them
    for c in range(len(ds.specs)):
        rows = ds.split[ds.clip == c]
        assert set(np.unique(rows)) == {0, 1, 2} and np.count_nonzero(np.diff(rows)) == 2
    first, twin = ds.split[ds.clip == 0], ds.split[ds.clip == 1]
    assert ds.specs[1].mirror and np.array_equal(first, twin)
    # one set of statistics over the training rows of all styles
    x_norm, _ = ds.normalisers()
    ref = fit_normaliser([ds.inputs[ds.split == 0].astype(np.float64)], js.LPNLayout(25).input_groups)
    np.testing.assert_allclose(x_norm.mean, ref.mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(x_norm.std, ref.std, rtol=1e-4)
    # cache: the same request loads the same arrays; a new setting builds a new file
    again = D.build_lpn_dataset(specs, cache_dir=tmp_path)
    np.testing.assert_array_equal(again.outputs, ds.outputs)
    assert again.specs == ds.specs and len(list(tmp_path.glob("lpn-*.npz"))) == 1
    D.build_lpn_dataset(specs[:2], cache_dir=tmp_path)
    assert len(list(tmp_path.glob("lpn-*.npz"))) == 2 and not list(tmp_path.glob("*.tmp"))
    # half-mirrored batches (2018): each row's twin is the same frame of the mirrored copy
    twins = ds.mirror_rows()
    assert (twins >= 0).all() and np.array_equal(twins[twins], np.arange(len(twins)))
    assert np.array_equal(ds.frame[twins], ds.frame) and all(ds.specs[c].mirror for c in ds.clip[twins[ds.clip == 0]])
    original_rows = np.flatnonzero(~np.array([sp.mirror for sp in ds.specs])[ds.clip])
    originals = [np.intersect1d(ds.rows_of_style(s, "train"), original_rows) for s in ds.styles]
    half = balanced_batches(originals, 32, mirror_of=twins)
    np.testing.assert_array_equal(half[:, 16:], twins[half[:, :16]])
    # balanced batches over the dataset's styles: one style per batch, in turn
    rows = [ds.rows_of_style(s, "train") for s in ds.styles]
    batches = balanced_batches(rows, 32)
    np.testing.assert_array_equal(ds.style[batches][:, 0], np.tile([0, 1], len(batches) // 2))
    assert (ds.style[batches] == ds.style[batches][:, :1]).all()


def test_changed_file_rebuilds(mocap, tmp_path):
    src = mocap / "xia/neutral_01_000.bvh"
    folder = tmp_path / "clips"
    folder.mkdir()
    shutil.copy(src, folder / "neutral_01_000.bvh")
    specs = C.specs_xia(folder, mirror=False)
    first = D.build_pfnn_dataset(specs, cache_dir=tmp_path / "cache")
    text = (folder / "neutral_01_000.bvh").read_text()
    head, motion = text.split("MOTION", 1)
    lines = motion.splitlines()
    for i in range(3, len(lines)):  # raise the root by one unit in every frame
        values = lines[i].split()
        values[1] = str(float(values[1]) + 1.0)
        lines[i] = " ".join(values)
    (folder / "neutral_01_000.bvh").write_text(head + "MOTION" + "\n".join(lines) + "\n")
    second = D.build_pfnn_dataset(specs, cache_dir=tmp_path / "cache")
    assert len(list((tmp_path / "cache").glob("pfnn-*.npz"))) == 2
    assert not np.array_equal(first.inputs, second.inputs)


def test_pfnn_dataset_from_xia_and_labelled_captures(mocap):
    xia = [s for s in C.specs_xia(mocap / "xia") if s.path.endswith("_01_000.bvh")]
    pfnn = C.specs_pfnn(mocap / "pfnn_excerpt")
    with pytest.raises(js.MotionDataError, match="NewCaptures02_000.bvh.*shorter than the trajectory window"):
        D.build_pfnn_dataset(xia + pfnn)
    with pytest.warns(UserWarning, match="skipped"):
        ds = D.build_pfnn_dataset(xia + pfnn, skip_short=True)
    assert ds.inputs.shape[1:] == (234,) and ds.outputs.shape[1:] == (400,)
    assert ds.styles[-1] == "pfnn" and len(ds.styles) == 9
    # labelled captures take their phase from the .phase file (every other 120 fps frame)
    c = next(i for i, s in enumerate(ds.specs) if s.path.endswith("NewCaptures01_000.bvh"))
    labels, _ = js.read_phase_labels(ds.specs[c].path)
    rows = ds.clip == c
    np.testing.assert_allclose(ds.phases[rows, 0], labels[2 * ds.frame[rows]], atol=1e-6)
    with pytest.raises(KeyError, match="unknown style"):
        ds.rows_of_style("zombie")


def test_style_mapping_errors(mocap):
    with pytest.raises(ValueError, match="name no file"):
        C.specs_from_folder(mocap / "xia", styles={"angry_01_000.bvh": "angry", "nope.bvh": "ghost"})
    with pytest.raises(ValueError, match="exactly one"):
        C.specs_from_folder(mocap / "xia")
    specs = C.specs_from_folder(mocap / "xia", pattern=r"(?P<style>[a-z]+)_01_000")
    assert len(specs) == 8 and not any(s.mirror for s in specs)


def test_a_skeleton_without_hands_is_refused(mocap):
    motion = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(0, 300)
    names = tuple(n.replace("Wrist", "Paw") for n in motion.names)
    with pytest.raises(js.MotionDataError, match="hands"):
        js.encode_lpn(motion.replace(names=names))


def test_few_shot_style_is_normalised_with_base_statistics(mocap):
    base = D.build_pfnn_dataset([s for s in C.specs_xia(mocap / "xia") if "_01_" in s.path and "neutral" in s.path])
    few = D.build_pfnn_dataset([s for s in C.specs_xia(mocap / "xia") if "_01_" in s.path and "proud" in s.path])
    x, y = few.normalised(base)
    x_norm, y_norm = base.normalisers()
    np.testing.assert_allclose(x, (few.inputs - x_norm.mean) / x_norm.std, rtol=1e-5, atol=1e-5)
    assert not np.allclose(x, few.normalised()[0])  # its own statistics would differ
    assert y.shape == few.outputs.shape
