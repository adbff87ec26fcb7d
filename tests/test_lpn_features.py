"""The 2022 LPN layout: sizes, style clips, decoding, mirroring and an independent frame check."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxstyle as js
from jaxstyle.data import lpn_features as lf
from jaxstyle.motion import character_frame as cf

CLIPS = ("100style/Angry/Angry_FW.bvh", "100style/Chicken/Chicken_BR.bvh", "100style/Neutral/Neutral_ID.bvh")


def test_layout_sizes():
    layout = lf.LPNLayout(25)
    assert (layout.input_size, layout.output_size, layout.joint_size) == (348, 342, 300)
    for groups, size in ((layout.input_groups, 348), (layout.output_groups, 342)):
        covered = np.zeros(size, int)
        for sl in groups.values():
            covered[sl] += 1
        assert (covered == 1).all()


@pytest.mark.parametrize("name", CLIPS)
def test_100style_clips_give_348_342_and_240x300_clips(mocap, name):
    motion = js.read_bvh(mocap / name)
    feats = lf.encode_lpn(motion)
    n = len(feats.frames)
    assert len(feats.bones) == 25 and feats.bones[-2:] == ("RightWrist_End", "LeftWrist_End")
    assert feats.inputs.shape == (n, 348) and feats.outputs.shape == (n, 342) and feats.phases.shape == (n, 8)
    assert feats.clips.shape[1:] == (240, 300)
    assert len(feats.clips) == (motion.num_frames - 1 - 240) // 120 + 1
    np.testing.assert_array_equal(np.diff(feats.clip_starts), 120)
    frames = cf.character_frames(motion)
    t = feats.frames
    decoded = lf.decode_lpn(feats.outputs, motion, origin=frames.origin[t[0]], yaw=frames.yaw[t[0]])
    err = np.abs(js.global_positions(decoded) - js.global_positions(motion)[t + 1]).max()
    assert err <= 1e-3 * js.skeleton_height(motion)


def test_outputs_against_an_independent_computation(mocap):
    motion = js.read_bvh(mocap / "100style/Angry/Angry_FW.bvh").frames(1000, 1400)
    phases = js.local_phases(motion)
    feats = lf.encode_lpn(motion, phases=phases)
    layout = lf.LPNLayout(25)
    g = layout.output_groups
    frames = cf.character_frames(motion)
    i = 50
    f = feats.frames[i]
    g_rot, g_pos = js.global_transforms(motion)
    to_frame = Rotation.from_rotvec([0.0, -frames.yaw[f], 0.0])  # outputs are in the input frame
    rot = to_frame * Rotation.from_quat(g_rot[f + 1][:, [1, 2, 3, 0]])
    fwd = feats.outputs[i, g["joint_forward"]].reshape(25, 3)
    np.testing.assert_allclose(fwd[:23], rot.apply([0, 0, 1]), atol=1e-9)
    np.testing.assert_allclose(fwd[23], fwd[motion.joint_index("RightWrist")])  # end site: parent's rotation
    pos = feats.outputs[i, g["joint_position"]].reshape(25, 3)[:23]
    np.testing.assert_allclose(pos, to_frame.apply(g_pos[f + 1] - frames.origin[f]), atol=1e-9)
    np.testing.assert_allclose(feats.outputs[i, g["local_phase"]], phases.features[f + 1].ravel())
    np.testing.assert_allclose(feats.outputs[i, g["local_phase_update"]],
                               (phases.features[f + 1] - phases.features[f]).ravel())
    np.testing.assert_array_equal(feats.outputs[:, g["foot_contact"]], phases.contacts[feats.frames + 1])
    np.testing.assert_allclose(feats.phases, phases.features[feats.frames].reshape(-1, 8))


def test_mirrored_clip_has_negated_x_and_swapped_limbs(mocap):
    motion = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(300, 900)
    a, b = lf.encode_lpn(motion), lf.encode_lpn(js.mirror(motion))
    g = lf.LPNLayout(25).input_groups
    traj, traj_m = a.inputs[:, g["trajectory_position"]], b.inputs[:, g["trajectory_position"]]
    np.testing.assert_allclose(traj_m[:, :12], -traj[:, :12], atol=1e-6)
    np.testing.assert_allclose(traj_m[:, 12:], traj[:, 12:], atol=1e-6)
    pairs = list(js.mirror_pairs(motion.names)) + [24, 23]  # the hand end sites swap too
    pos = a.inputs[:, g["joint_position"]].reshape(len(a.inputs), 25, 3)
    pos_m = b.inputs[:, g["joint_position"]].reshape(len(a.inputs), 25, 3)
    np.testing.assert_allclose(pos_m[..., 0], -pos[:, pairs, 0], atol=1e-6)
    np.testing.assert_allclose(pos_m[..., 1:], pos[:, pairs, 1:], atol=1e-6)


def test_short_clip_errors_and_has_no_style_clip(mocap):
    motion = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh")
    assert len(lf.encode_lpn(motion.frames(0, 200)).clips) == 0
    with pytest.raises(js.MotionDataError, match="trajectory window"):
        lf.encode_lpn(motion.frames(0, 100))
    with pytest.raises(ValueError, match="outputs must have shape"):
        lf.decode_lpn(np.zeros((3, 341)), motion)


def test_rows_carry_the_labellers_global_phase(mocap):
    """The global phase of every LPN row is :func:`jaxstyle.global_phase` of the clip at the row's
    frame (the PFNN backbones' gate), on a clip and on its mirror; a given phase is used as given."""
    motion = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(300, 900)
    for m in (motion, js.mirror(motion)):
        feats = lf.encode_lpn(m)
        labels = js.global_phase(m)
        np.testing.assert_array_equal(feats.global_phase, labels[feats.frames])
        assert np.ptp(feats.global_phase) > 0.5  # a walk: the phase goes round
    given = np.linspace(0, 3, motion.num_frames) % 1.0
    feats = lf.encode_lpn(motion, global_phase_T=given)
    np.testing.assert_array_equal(feats.global_phase, given[feats.frames])
    with pytest.raises(ValueError, match="global_phase_T must have shape"):
        lf.encode_lpn(motion, global_phase_T=given[:-1])


def test_lpn_dataset_global_phase_equals_the_labeller_on_the_same_frames(tmp_path):
    """Built (and reloaded from its cache), an LPN dataset's ``global_phase`` equals the labeller
    run on each clip (mirrored copies included) at each row's frame; the local phases stay 8 columns."""
    from jaxstyle.data import clips, datasets, procedural
    from jaxstyle.mason2022 import styledata

    root = procedural.write_dataset(tmp_path / "p", ["Neutral", "Limping"], ("FW",), seconds=8)
    specs = clips.specs_100style(root, gaits=("FW",))
    assert any(s.mirror for s in specs)
    for _ in range(2):  # built, then from the cache
        ds = datasets.build_lpn_dataset(specs, cache_dir=tmp_path / "cache")
        assert ds.phases.shape == (len(ds.inputs), 8) and ds.global_phase.shape == (len(ds.inputs),)
        for i, spec in enumerate(ds.specs):
            rows = np.flatnonzero(ds.clip == i)
            labels = js.global_phase(datasets.load_clip(spec)).astype(np.float32)
            np.testing.assert_array_equal(ds.global_phase[rows], labels[ds.frame[rows]])
    skeleton = datasets.load_clip(ds.specs[0])
    data = styledata.style_data(ds, skeleton, backbone="pfnn")
    np.testing.assert_array_equal(data.gate, ds.global_phase[:, None])
    np.testing.assert_array_equal(styledata.style_data(ds, skeleton).gate, ds.phases)  # the LPN's: local phases
    stale = dataclasses.replace(ds, global_phase=np.zeros(0, np.float32))  # a cache from before the field
    with pytest.raises(ValueError, match="global phases for"):
        styledata.style_data(stale, skeleton, backbone="pfnn")


def test_layout_of_an_input_size_round_trips_and_refuses_other_sizes():
    for bones in (1, 23, 25, 31):
        assert lf.LPNLayout.of_inputs(lf.LPNLayout(bones).input_size) == lf.LPNLayout(bones)
    for bad in (48, 47, lf.LPNLayout(25).input_size + 5, lf.LPNLayout(25).output_size):
        with pytest.raises(ValueError, match="not an LPN input size"):
            lf.LPNLayout.of_inputs(bad)
