"""``--joint-map`` / ``joint_map=``: a skeleton whose feet are not found by name.

A real 100STYLE clip is written again with its ankles and toes renamed to names that say neither
the joint nor its side. Without a map the dataset builders fail with one line that names the
``--joint-map`` flag; with the map they build exactly the rows of the original file.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from jaxstyle import cli
from jaxstyle.data import datasets, folders
from jaxstyle.errors import MotionDataError
from jaxstyle.motion import bvh, skeleton, transform
from jaxstyle.motion.skeleton import JointMap, read_joint_map

RENAMED = {"LeftAnkle": "PiedGauche", "RightAnkle": "PiedDroit", "LeftToe": "OrteilGauche", "RightToe": "OrteilDroit"}
MAP_TOML = 'feet = ["PiedGauche", "PiedDroit"]\nleft_toe = "OrteilGauche"\nright_toe = "OrteilDroit"\n'
SECONDS = 12.0  # just over the 11 s trajectory window: a few rows per clip keep the test quick


def _write_style_folder(mocap: Path, root: Path, renamed: bool) -> Path:
    text = (mocap / "100style" / "Neutral" / "Neutral_FW.bvh").read_text()
    if renamed:
        for old, new in RENAMED.items():
            text, n = re.subn(rf"\bJOINT {old}\b", f"JOINT {new}", text)
            assert n == 1
    (root / "Neutral").mkdir(parents=True)
    (root / "Neutral" / "Neutral_FW.bvh").write_text(text)
    return root


@pytest.fixture
def folders_pair(mocap, tmp_path):
    original = _write_style_folder(mocap, tmp_path / "original", renamed=False)
    renamed = _write_style_folder(mocap, tmp_path / "renamed", renamed=True)
    map_path = tmp_path / "joints.toml"
    map_path.write_text(MAP_TOML)
    return original, renamed, map_path


def test_renamed_feet_fail_without_the_map_and_match_the_original_with_it(folders_pair):
    original, renamed, map_path = folders_pair
    specs = folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS)
    assert [s.mirror for s in specs] == [False, True]
    with pytest.raises(MotionDataError, match=r"--joint-map FILE") as e:
        datasets.build_pfnn_dataset(specs)
    assert "Neutral_FW.bvh" in str(e.value) and "ankles" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(MotionDataError, match=r"--joint-map FILE"):  # the mirrored copy alone: pairing fails first
        datasets.build_pfnn_dataset(specs[1:])

    jmap = read_joint_map(map_path)
    ref = datasets.build_pfnn_dataset(folders.clip_specs(original, ["Neutral"], max_seconds=SECONDS))
    got = datasets.build_pfnn_dataset(folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS, joint_map=jmap))
    assert len(got.inputs) == len(ref.inputs) > 0
    np.testing.assert_array_equal(got.inputs, ref.inputs)
    np.testing.assert_array_equal(got.outputs, ref.outputs)
    np.testing.assert_array_equal(got.phases, ref.phases)
    # the builders' own argument does the same
    again = datasets.build_pfnn_dataset(folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS), joint_map=jmap)
    np.testing.assert_array_equal(again.inputs, ref.inputs)


@pytest.mark.slow
def test_lpn_rows_with_the_map_match_the_original(folders_pair):
    """The LPN rows (hands, local phases of the renamed feet, global phase) too (16 s)."""
    original, renamed, map_path = folders_pair
    jmap = read_joint_map(map_path)
    ref = datasets.build_lpn_dataset(folders.clip_specs(original, ["Neutral"], max_seconds=SECONDS)[:1])
    got = datasets.build_lpn_dataset(folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS)[:1], joint_map=jmap)
    np.testing.assert_array_equal(got.inputs, ref.inputs)
    np.testing.assert_array_equal(got.outputs, ref.outputs)
    np.testing.assert_array_equal(got.phases, ref.phases)


def test_the_map_is_part_of_the_cache_key(folders_pair, tmp_path):
    _, renamed, map_path = folders_pair
    specs = folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS)[:1]
    jmap = read_joint_map(map_path)
    cache = tmp_path / "cache"
    first = datasets.build_pfnn_dataset(specs, joint_map=jmap, cache_dir=cache)
    loaded = datasets.build_pfnn_dataset(specs, joint_map=jmap, cache_dir=cache)  # from the cache
    assert loaded.specs[0].joint_map == jmap
    np.testing.assert_array_equal(loaded.inputs, first.inputs)
    # swapping the toes is another map: another cache file, not the old rows
    swapped = JointMap.from_mapping({"feet": ["PiedGauche", "PiedDroit"], "toes": ["OrteilDroit", "OrteilGauche"]})
    datasets.build_pfnn_dataset(specs, joint_map=swapped, cache_dir=cache)
    assert len(list(cache.glob("pfnn-*.npz"))) == 2


def test_map_mirror_pairs_and_finders():
    names = ("Hips", "PiedGauche", "PiedDroit", "Spine")
    jmap = JointMap.from_mapping({"ankles": ["PiedGauche", "PiedDroit"]})
    np.testing.assert_array_equal(skeleton.mirror_pairs(names, joint_map=jmap), [0, 2, 1, 3])
    np.testing.assert_array_equal(skeleton.mirror_pairs(names), [0, 1, 2, 3])
    full = ("Hips", "LeftUpLeg", "RightUpLeg", "LeftArm", "RightArm", "PiedGauche", "PiedDroit", "LeftToeBase",
            "RightToeBase", "LeftHand", "RightHand")
    found = skeleton.find_feet_and_hands(full, joint_map=jmap)
    assert found == {"ankles": ("PiedGauche", "PiedDroit"), "toes": ("LeftToeBase", "RightToeBase"),
                     "hands": ("LeftHand", "RightHand")}
    with pytest.raises(MotionDataError, match=r"ankles.*--joint-map FILE"):
        skeleton.find_feet_and_hands(full)
    hips = JointMap.from_mapping({"hips": ["RightUpLeg", "LeftUpLeg"]})  # a map wins over the names
    assert skeleton.find_hips_and_shoulders(full, joint_map=hips)[0] == ("RightUpLeg", "LeftUpLeg")


@pytest.mark.parametrize("text, suffix, message", [
    ('foot_size = ["a", "b"]\n', ".toml", r"joints\.toml: key 'foot_size': unknown role; the roles are hips"),
    ('feet = "PiedGauche"\n', ".toml", r"joints\.toml: key 'feet': expected \[left, right\] joint names"),
    ('left_toe = "OrteilGauche"\n', ".toml", r"joints\.toml: role 'toes': the right joint is missing"),
    ('feet = [\n', ".toml", r"joints\.toml: not valid TOML"),
    ('{"feet": ["PiedGauche"]}', ".json", r"joints\.json: key 'feet': expected \[left, right\]"),
    ('[1, 2]', ".json", r"joints\.json: a joint map is a table"),
])
def test_bad_map_files_name_the_file_and_key(tmp_path, text, suffix, message):
    path = tmp_path / f"joints{suffix}"
    path.write_text(text)
    with pytest.raises(MotionDataError, match=message):
        read_joint_map(path)


def test_a_joint_missing_from_the_skeleton_names_the_map_and_key(folders_pair, tmp_path):
    _, renamed, _ = folders_pair
    path = tmp_path / "joints.json"
    path.write_text(json.dumps({"ankles": ["PiedGauche", "PiedDroite"]}))
    specs = folders.clip_specs(renamed, ["Neutral"], max_seconds=SECONDS, joint_map=read_joint_map(path))
    with pytest.raises(MotionDataError, match=r"joints\.json: key 'ankles': right joint 'PiedDroite' is not in the "
                                              r"skeleton of .*Neutral_FW\.bvh"):
        datasets.build_pfnn_dataset(specs)


def test_mirror_uses_the_motion_map(mocap):
    motion = bvh.read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh").frames(0, 30)
    names = tuple(RENAMED.get(n, n) for n in motion.names)
    renamed = motion.replace(names=names)
    with pytest.raises(MotionDataError, match="--joint-map"):
        transform.mirror(renamed)
    jmap = JointMap.from_mapping({"ankles": ["PiedGauche", "PiedDroit"], "toes": ["OrteilGauche", "OrteilDroit"]})
    got = transform.mirror(renamed.replace(joint_map=jmap))
    want = transform.mirror(motion)
    np.testing.assert_array_equal(got.rotations, want.rotations)
    np.testing.assert_array_equal(got.local_positions, want.local_positions)


def run_cli(argv, capsys):
    capsys.readouterr()
    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as e:
        rc = e.code
    return rc, capsys.readouterr()


def test_cli_joint_map_flag(folders_pair, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _, renamed, map_path = folders_pair
    common = ["data", "prepare", "--data", renamed, "--run", tmp_path / "r", "--max-seconds", SECONDS, "--quiet"]
    rc, out = run_cli(common, capsys)
    lines = out.err.strip().splitlines()
    assert rc == 1 and len(lines) == 1 and "Traceback" not in out.err
    assert "--joint-map FILE" in lines[0] and "Neutral_FW.bvh" in lines[0]

    bad = tmp_path / "bad.toml"
    bad.write_text('heel = ["a", "b"]\n')
    for path, wanted in ((bad, f"--joint-map {bad}: key 'heel': unknown role"),
                         (tmp_path / "none.toml", f"--joint-map {tmp_path / 'none.toml'}: no such file"),
                         (tmp_path, f"--joint-map {tmp_path}: is a folder")):
        rc, out = run_cli(common + ["--joint-map", path], capsys)
        lines = out.err.strip().splitlines()
        assert rc == 1 and len(lines) == 1 and wanted in lines[0], out.err

    rc, out = run_cli(common + ["--joint-map", map_path], capsys)
    assert rc == 0, out.err
    assert "| Neutral | 2 |" in out.out


@pytest.mark.parametrize("command", [["data", "prepare"], ["train-base"], ["sweep"], ["lpn"], ["demo"]])
def test_every_style_folder_command_has_the_flag(command, capsys):
    rc, out = run_cli(command + ["--help"], capsys)
    assert rc == 0 and "--joint-map FILE" in out.out
