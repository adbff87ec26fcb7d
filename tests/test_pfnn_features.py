"""The 2018 PFNN feature layout: sizes, conventions against scipy, mirroring, decoding."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import jaxstyle as js
from jaxstyle.data import pfnn_features as pf
from jaxstyle.motion import character_frame as cf

CLIPS = ("xia/proud_01_000.bvh", "xia/strutting_13_000.bvh", "pfnn_excerpt/NewCaptures01_000.bvh",
         "pfnn_excerpt/WalkingUpSteps09_000_mirror.bvh")


def _load(mocap, name):
    return js.resample(js.read_bvh(mocap / name), 60)


def test_layout_sizes():
    layout = pf.PFNNLayout(31)
    assert (layout.input_size, layout.output_size) == (234, 400)
    for groups, size in ((layout.input_groups, 234), (layout.output_groups, 400)):
        covered = np.zeros(size, int)
        for sl in groups.values():
            covered[sl] += 1
        assert (covered == 1).all()  # the groups tile the vector
    assert pf.PFNNLayout(23).input_size == 48 + 6 * 23


@pytest.mark.parametrize("name", CLIPS)
def test_cmu_clips_give_234_to_400_and_decode_back(mocap, name):
    motion = _load(mocap, name)
    phase = js.global_phase(motion)
    x, y, t = pf.encode_pfnn(motion, phase)
    assert x.shape == (len(t), 234) and y.shape == (len(t), 400)
    np.testing.assert_array_equal(t, np.arange(60, motion.num_frames - 51))  # whole windows only
    frames = cf.character_frames(motion)
    decoded, dphase = pf.decode_pfnn(y, motion, origin=frames.origin[t[0]], yaw=frames.yaw[t[0]], phase=phase[t[0]])
    want = js.global_positions(motion)[t + 1]
    got = js.global_positions(decoded)
    assert np.abs(got - want).max() <= 1e-3 * js.skeleton_height(motion)
    assert js.circular_distance(dphase, phase[t + 1]).max() < 1e-9


def test_features_match_an_independent_computation(mocap):
    """One frame recomputed with scipy rotations and plain trigonometry."""
    motion = _load(mocap, "xia/proud_01_000.bvh")
    phase = js.global_phase(motion)
    x, y, t = pf.encode_pfnn(motion, phase)
    frames = cf.character_frames(motion)
    i = len(t) // 2
    f = t[i]
    g_rot, g_pos = js.global_transforms(motion)
    to_root = Rotation.from_rotvec([0.0, -frames.yaw[f + 1], 0.0])
    rot = to_root * Rotation.from_quat(g_rot[f + 1][:, [1, 2, 3, 0]])  # scipy is (x, y, z, w)
    g = pf.PFNNLayout(motion.num_joints).output_groups
    np.testing.assert_allclose(y[i, g["joint_forward"]].reshape(-1, 3), rot.apply([0, 0, 1]), atol=1e-9)
    np.testing.assert_allclose(y[i, g["joint_up"]].reshape(-1, 3), rot.apply([0, 1, 0]), atol=1e-9)
    local = to_root.apply(g_pos[f + 1] - frames.origin[f + 1])
    np.testing.assert_allclose(y[i, g["joint_position"]].reshape(-1, 3), local, atol=1e-9)
    # the current trajectory sample sits at the origin, facing +Z
    xg = pf.PFNNLayout(motion.num_joints).input_groups
    traj = x[i, xg["trajectory_position"]].reshape(2, 12)
    dirs = x[i, xg["trajectory_direction"]].reshape(2, 12)
    np.testing.assert_allclose(traj[:, 6], 0.0, atol=1e-9)
    np.testing.assert_allclose(dirs[:, 6], [0.0, 1.0], atol=1e-9)
    # the root joint is above the origin; the root's speed matches the velocity output
    np.testing.assert_allclose(x[i, xg["joint_position"]][[0, 2]], 0.0, atol=1e-9)
    step = np.linalg.norm(frames.origin[f + 1] - frames.origin[f])
    assert np.hypot(y[i, 0], y[i, 1]) == pytest.approx(step)


def test_mirrored_clip_has_negated_x_and_swapped_limbs(mocap):
    motion = _load(mocap, "pfnn_excerpt/NewCaptures01_000.bvh")
    mirrored = js.mirror(motion)
    phase = js.global_phase(motion)
    x, y, _ = pf.encode_pfnn(motion, phase)
    xm, ym, _ = pf.encode_pfnn(mirrored, phase)
    g = pf.PFNNLayout(motion.num_joints).input_groups
    traj, traj_m = x[:, g["trajectory_position"]], xm[:, g["trajectory_position"]]
    np.testing.assert_allclose(traj_m[:, :12], -traj[:, :12], atol=1e-6)  # x negated
    np.testing.assert_allclose(traj_m[:, 12:], traj[:, 12:], atol=1e-6)   # z kept
    pairs = js.mirror_pairs(motion.names)
    pos = x[:, g["joint_position"]].reshape(len(x), -1, 3)
    pos_m = xm[:, g["joint_position"]].reshape(len(x), -1, 3)
    np.testing.assert_allclose(pos_m[:, :, 0], -pos[:, pairs, 0], atol=1e-6)
    np.testing.assert_allclose(pos_m[:, :, 1:], pos[:, pairs, 1:], atol=1e-6)


def test_too_short_and_wrong_shapes(mocap):
    motion = _load(mocap, "xia/angry_18_000.bvh")  # 80 frames at 120 fps: 40 at 60 fps
    with pytest.raises(js.MotionDataError, match="trajectory window"):
        pf.encode_pfnn(motion, np.zeros(motion.num_frames))
    with pytest.raises(ValueError, match="phase must have shape"):
        pf.encode_pfnn(motion, np.zeros(3))
    with pytest.raises(ValueError, match="outputs must have shape"):
        pf.decode_pfnn(np.zeros((5, 399)), motion)


def test_contact_outputs_round_trip_through_the_layout(mocap):
    """The optional contact outputs: appended after the paper's 400 values (every other slice
    unchanged), equal to the contact detector's labels of the predicted frame, read back by
    output_contacts, and ignored by the decoder."""
    motion = js.resample(js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(0, 400), 60)
    phase = js.global_phase(motion)
    plain, with_c = pf.PFNNLayout(motion.num_joints), pf.PFNNLayout(motion.num_joints, contacts=True)
    assert with_c.output_size == plain.output_size + 4
    assert {k: v for k, v in with_c.output_groups.items() if k != "foot_contact"} == plain.output_groups
    assert with_c.output_groups["foot_contact"] == slice(plain.output_size, plain.output_size + 4)
    x0, y0, t0 = pf.encode_pfnn(motion, phase)
    x, y, t = pf.encode_pfnn(motion, phase, contacts=True)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(t, t0)
    np.testing.assert_array_equal(y[:, :plain.output_size], y0)
    c = js.foot_contacts(motion)
    want = np.concatenate([c.heel, c.toe], axis=1)[t + 1].astype(float)
    assert 0.1 < want.mean() < 0.9  # a walk: feet both on and off the floor
    np.testing.assert_array_equal(pf.output_contacts(y, motion.num_joints), want)
    assert pf.output_contacts(y0, motion.num_joints) is None
    assert pf.PFNNLayout.from_output_size(motion.num_joints, y.shape[1]) == with_c
    a, _ = pf.decode_pfnn(y, motion)
    b, _ = pf.decode_pfnn(y0, motion)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.local_positions, b.local_positions)
    with pytest.raises(ValueError, match="contacts must have shape"):
        pf.encode_pfnn(motion, phase, contacts=np.zeros((5, 4)))
    with pytest.raises(ValueError, match="fit no PFNN layout"):
        pf.PFNNLayout.from_output_size(motion.num_joints, y.shape[1] + 1)
