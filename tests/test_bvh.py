"""BVH reading and writing on all shared motion capture, and on synthetic files of every shape."""

from __future__ import annotations

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.motion.bvh import frame_rate
from tests.conftest import all_bvh
from tests.reference_bvh import reference_fk


def test_every_shared_file_matches_manifest_and_reference_fk(mocap, manifest):
    files = all_bvh(mocap)
    assert len(files) >= 70, "expected the whole shared sample"
    seen_joint_counts = set()
    for path in files:
        rel = path.relative_to(mocap).as_posix()
        motion = js.read_bvh(path)
        assert frame_rate(path) == motion.fps, rel  # the header alone gives the same rate
        row = manifest.get(rel)
        if row is not None:  # xia/rest.bvh is the one file the manifest does not list in full
            assert motion.num_frames == int(row["frames"]), rel
            assert motion.fps == pytest.approx(float(row["fps"]), rel=1e-9), rel
            assert motion.num_joints == int(row["joints"]), rel
        seen_joint_counts.add(motion.num_joints)
        height = js.skeleton_height(motion)
        ref_pos, ref_ends = reference_fk(path)
        ours = js.global_positions(motion, end_sites=True)
        expected = np.concatenate([ref_pos, ref_ends], axis=1)
        err = np.abs(ours - expected).max() / height
        assert err < 1e-4, f"{rel}: FK differs from the scipy reference by {err:.2e} of skeleton height"
    assert seen_joint_counts == {23, 31}


def test_manifest_lists_every_shared_bvh(mocap, manifest):
    listed = set(manifest)
    on_disk = {p.relative_to(mocap).as_posix() for p in all_bvh(mocap)}
    assert on_disk - listed <= {"xia/rest.bvh"}


@pytest.mark.parametrize("precision", [6])
def test_write_round_trip_on_every_shared_file(mocap, tmp_path, precision):
    for path in all_bvh(mocap):
        motion = js.read_bvh(path)
        out = js.write_bvh(motion, tmp_path / path.name, precision=precision)
        back = js.read_bvh(out)
        assert back.names == motion.names and back.channels == motion.channels
        np.testing.assert_array_equal(back.parents, motion.parents)
        assert back.fps == motion.fps and back.num_frames == motion.num_frames
        err = np.abs(js.global_positions(back, end_sites=True) - js.global_positions(motion, end_sites=True)).max()
        assert err / js.skeleton_height(motion) < 1e-4, f"{path.name}: round trip error {err}"


def test_skeleton_heights_and_units(mocap):
    style = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh")
    cmu = js.read_bvh(mocap / "xia/neutral_01_000.bvh")
    assert 150 < js.skeleton_height(style) < 200  # centimetres
    assert 20 < js.skeleton_height(cmu) < 30  # Holden's CMU units (about 24 tall)
    assert js.bone_lengths(style)[0] == 0.0 and np.all(js.bone_lengths(style)[1:] >= 0)


# ------------------------------------------------------------------ synthetic files of every shape

GENERAL = """HIERARCHY
ROOT Pelvis Root {
\tOFFSET 1 2 3
\tCHANNELS 6 Xposition Yposition Zposition Xrotation Zrotation Yrotation
\tJOINT Spine { OFFSET 0 10 0
\t\tCHANNELS 6 Zrotation Xposition Yrotation Zposition Xrotation Yposition
\t\tJOINT Head
\t\t{
\t\t\tOFFSET 0 5 1
\t\t\tCHANNELS 2 Yrotation Xrotation
\t\t\tEnd Site
\t\t\t{
\t\t\t\tOFFSET 0 3 0
\t\t\t}
\t\t}
\t}
\tJOINT Tail
\t{
\t\tOFFSET 0 -2 -4
\t\tCHANNELS 1 Zrotation
\t\tJOINT TailTip
\t\t{
\t\t\tOFFSET 0 0 -3
\t\t\tCHANNELS 0
\t\t\tEnd Site { OFFSET 0 0 -1 }
\t\t\tEnd Site { OFFSET 0 1 -1 }
\t\t}
\t}
}
ROOT Prop
{
\tOFFSET 5 0 0
\tCHANNELS 3 Yposition Yrotation Xrotation
}
MOTION
Frames: 3
Frame Time: 0.0333333
"""


def _general_rows(rng, n=3):
    return rng.uniform(-90, 90, size=(n, 6 + 6 + 2 + 1 + 3))


def _general_text(rng, newline="\n"):
    rows = _general_rows(rng)
    body = "\n".join(" ".join(f"{v:.6f}" for v in r) + "  " for r in rows)  # trailing spaces
    return (GENERAL + body + "\n").replace("\n", newline), rows


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_general_hierarchy_against_reference(tmp_path, newline):
    text, rows = _general_text(np.random.default_rng(1), newline)
    path = tmp_path / "general.bvh"
    path.write_bytes(text.encode())
    motion = js.read_bvh(path)
    assert motion.names == ("Pelvis Root", "Spine", "Head", "Tail", "TailTip", "Prop")
    np.testing.assert_array_equal(motion.parents, [-1, 0, 1, 0, 3, -1])
    assert motion.fps == 30.0
    assert motion.channels[4] == () and len(motion.channels[2]) == 2
    np.testing.assert_array_equal(motion.end_site_parents, [2, 4, 4])
    # Spine's position channels (file columns X=7, Z=9, Y=11) replace its offset.
    np.testing.assert_allclose(motion.local_positions[:, 1], rows[:, [7, 11, 9]], atol=1e-6)
    # Prop animates only Y; X and Z keep the offset.
    np.testing.assert_allclose(motion.local_positions[:, 5, [0, 2]], [[5, 0]] * 3)
    ref_path = tmp_path / "general_lf.bvh"  # the reference reader wants plain newlines
    ref_path.write_text(text.replace("\r\n", "\n"))
    ref_pos, ref_ends = reference_fk(ref_path)
    np.testing.assert_allclose(js.global_positions(motion), ref_pos, atol=1e-9)
    np.testing.assert_allclose(js.global_positions(motion, end_sites=True)[:, 6:], ref_ends, atol=1e-9)


def test_general_hierarchy_writes_back_where_representable(tmp_path):
    text, _ = _general_text(np.random.default_rng(2))
    motion = js.parse_bvh(text)
    # Head has 2 rotation channels and Tail 1: rewrite them with 3 to represent any rotation.
    channels = list(motion.channels)
    channels[2] = ("Zrotation", "Xrotation", "Yrotation")
    channels[3] = ("Yrotation", "Xrotation", "Zrotation")
    channels[5] = ("Yposition", "Xrotation", "Yrotation", "Zrotation")
    out = js.write_bvh(motion, tmp_path / "out.bvh", channels=tuple(channels))
    back = js.read_bvh(out)
    np.testing.assert_allclose(js.global_positions(back, end_sites=True),
                               js.global_positions(motion, end_sites=True), atol=1e-5)
    with pytest.raises(js.MotionDataError, match="cannot write 2 rotation channels"):
        js.format_bvh(motion)


def test_generated_motion_without_channels_gets_default_layout():
    text, _ = _general_text(np.random.default_rng(3))
    motion = js.parse_bvh(text)
    bare = motion.replace(channels=((),) * motion.num_joints)
    back = js.parse_bvh(js.format_bvh(bare))
    assert back.channels[0] == js.motion.bvh.DEFAULT_ROOT_CHANNELS
    assert back.channels[2] == js.motion.bvh.DEFAULT_JOINT_CHANNELS
    # Spine translates, so it gets position channels too.
    assert back.channels[1] == js.motion.bvh.DEFAULT_ROOT_CHANNELS
    np.testing.assert_allclose(js.global_positions(back), js.global_positions(motion), atol=1e-5)


def test_fps_is_snapped_only_near_integers():
    base = "HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition Zposition\n}\nMOTION\nFrames: 1\n"
    assert js.parse_bvh(base + "Frame Time: .0083333\n0 0 0\n").fps == 120.0
    assert js.parse_bvh(base + "Frame Time: 0.016667\n0 0 0\n").fps == 60.0
    assert js.parse_bvh(base + "Frame Time: 0.04\n0 0 0\n").fps == 25.0
    assert js.parse_bvh(base + "Frame Time: 0.0123\n0 0 0\n").fps == pytest.approx(1 / 0.0123)


def test_writer_refuses_to_drop_an_unwritable_translation():
    text, _ = _general_text(np.random.default_rng(4))
    motion = js.parse_bvh(text)
    # Prop animates only Yposition; rotating the whole motion moves it along X and Z too.
    turned = js.rotate(motion, js.motion.quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), 0.5))
    channels = list(turned.channels)
    channels[2] = ("Zrotation", "Xrotation", "Yrotation")
    channels[3] = ("Yrotation", "Xrotation", "Zrotation")
    channels[5] = ("Yposition", "Xrotation", "Yrotation", "Zrotation")
    with pytest.raises(js.MotionDataError, match="'Prop' moves along Xposition Zposition"):
        js.format_bvh(turned, tuple(channels))
    channels[5] = js.motion.bvh.DEFAULT_ROOT_CHANNELS
    back = js.parse_bvh(js.format_bvh(turned, tuple(channels)))
    np.testing.assert_allclose(js.global_positions(back), js.global_positions(turned), atol=1e-5)
