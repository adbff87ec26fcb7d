"""Foot contact IK (2022 section 4.4): the two-bone solver, contact targets and the fix on a real walk."""

from __future__ import annotations

import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.labels.contacts import runs
from jaxstyle.motion import Motion, kinematics, quat
from jaxstyle.output import footik
from tests.synthetic_legs import NAMES, OFFSETS, PARENTS

FPS = 60.0


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _random_chains(rng, n):
    hip = rng.normal(size=(n, 3)) * 10
    knee = hip + rng.normal(size=(n, 3))
    ankle = knee + rng.normal(size=(n, 3))
    return hip, knee, ankle, np.linalg.norm(knee - hip, axis=-1), np.linalg.norm(ankle - knee, axis=-1)


def _reference_knee(hip, target, pole, l1, l2):
    """Circle-circle intersection in the plane of hip, target and pole (the numpy reference)."""
    e1 = _unit(target - hip)
    e2 = _unit(pole - np.sum(pole * e1, -1, keepdims=True) * e1)
    d = np.linalg.norm(target - hip, axis=-1)
    x = (d ** 2 + l1 ** 2 - l2 ** 2) / (2 * d)
    y = np.sqrt(l1 ** 2 - x ** 2)
    return hip + x[:, None] * e1 + y[:, None] * e2


def test_two_bone_ik_reaches_reachable_targets_exactly():
    rng = np.random.default_rng(0)
    hip, knee, ankle, l1, l2 = _random_chains(rng, 500)
    dist = rng.uniform(np.abs(l1 - l2) + 1e-3, l1 + l2 - 1e-3)
    target = hip + _unit(rng.normal(size=(500, 3))) * dist[:, None]
    pole = rng.normal(size=(500, 3))
    ik = footik.two_bone_ik(hip, knee, ankle, target, pole)
    np.testing.assert_allclose(ik.ankle, target, atol=1e-12)
    np.testing.assert_allclose(ik.knee, _reference_knee(hip, target, pole, l1, l2), atol=1e-9)
    # the rotations carry the old bones onto the new ones, so lengths are those of the old bones
    new_knee = hip + quat.rotate(ik.hip_rotation, knee - hip)
    new_ankle = new_knee + quat.rotate(ik.knee_rotation, ankle - knee)
    np.testing.assert_allclose(new_knee, ik.knee, atol=1e-12)
    np.testing.assert_allclose(new_ankle, target, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_knee - hip, axis=-1), l1, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_ankle - new_knee, axis=-1), l2, rtol=1e-12)
    # hinge: both rotations take the old leg plane's normal onto the new one (the knee only bends about it)
    old_normal = _unit(np.cross(knee - hip, ankle - knee))
    new_normal = _unit(np.cross(ik.knee - hip, ik.ankle - ik.knee))
    np.testing.assert_allclose(quat.rotate(ik.hip_rotation, old_normal), new_normal, atol=1e-9)
    np.testing.assert_allclose(quat.rotate(ik.knee_rotation, old_normal), new_normal, atol=1e-9)


def test_two_bone_ik_target_at_the_current_ankle_changes_nothing():
    rng = np.random.default_rng(1)
    hip, knee, ankle, _, _ = _random_chains(rng, 200)
    ik = footik.two_bone_ik(hip, knee, ankle, ankle, knee - hip)
    np.testing.assert_allclose(ik.knee, knee, atol=1e-9)
    np.testing.assert_allclose(np.abs(ik.hip_rotation[:, 0]), 1.0, atol=1e-9)
    np.testing.assert_allclose(np.abs(ik.knee_rotation[:, 0]), 1.0, atol=1e-9)


def test_two_bone_ik_unreachable_targets_give_a_straight_or_folded_leg():
    rng = np.random.default_rng(2)
    hip, knee, ankle, l1, l2 = _random_chains(rng, 300)
    direction = _unit(rng.normal(size=(300, 3)))
    far = hip + direction * (l1 + l2 + rng.uniform(0.01, 5.0, 300))[:, None]
    ik = footik.two_bone_ik(hip, knee, ankle, far, rng.normal(size=(300, 3)))
    np.testing.assert_allclose(ik.knee, hip + direction * l1[:, None], atol=1e-9)
    np.testing.assert_allclose(ik.ankle, hip + direction * (l1 + l2)[:, None], atol=1e-9)
    new_ankle = hip + quat.rotate(ik.hip_rotation, knee - hip) + quat.rotate(ik.knee_rotation, ankle - knee)
    np.testing.assert_allclose(new_ankle, ik.ankle, atol=1e-9)
    near = hip + direction * (np.abs(l1 - l2) * rng.uniform(0.0, 0.9, 300))[:, None]
    ik = footik.two_bone_ik(hip, knee, ankle, near, rng.normal(size=(300, 3)))
    np.testing.assert_allclose(ik.ankle, hip + direction * np.abs(l1 - l2)[:, None], atol=1e-9)


def test_contact_targets_hold_then_blend_back_without_jumps():
    t = np.arange(60)
    ankle = np.stack([2.0 * t, np.sin(t / 5.0), -1.0 * t], -1)  # always moving
    contact = (t >= 10) & (t < 20) | (t >= 22) & (t < 30)  # the second run starts inside the first's blend
    target, active = footik.contact_targets(ankle, contact, blend_frames=5)
    np.testing.assert_array_equal(target[10:20], np.broadcast_to(ankle[10], (10, 3)))
    np.testing.assert_array_equal(target[:10], ankle[:10])
    np.testing.assert_array_equal(target[35:], ankle[35:])
    np.testing.assert_array_equal(active, (t >= 10) & (t < 35))
    # the second run holds where the blended target was (nothing jumps), then fades out over 5 frames
    np.testing.assert_allclose(target[22:30], np.broadcast_to(target[22], (8, 3)), rtol=0, atol=1e-12)
    # no jumps: a step is at most the ankle's plus the fade's share (smoothstep slope <= 1.5 / (blend + 1))
    offset = np.linalg.norm(target - ankle, axis=-1)
    ankle_step = np.linalg.norm(np.diff(ankle, axis=0), axis=-1).max()
    assert np.linalg.norm(np.diff(target, axis=0), axis=-1).max() <= ankle_step + 1.5 * offset.max() / 6
    abrupt, _ = footik.contact_targets(ankle, contact, blend_frames=0)
    assert np.linalg.norm(np.diff(abrupt, axis=0), axis=-1).max() > 8 * ankle_step  # without a blend: a jump
    assert np.all(np.diff(offset[29:36]) < 0)  # the fade-out shrinks monotonically to 0


# --- a synthetic leg, without motion capture ---



def _standing(num_frames: int, knee_bend_deg: float = 20.0, source: str | None = "synthetic.bvh",
              names=NAMES) -> Motion:
    """Both knees bent, the root moving forward at 0.3 m/s (the feet slide along)."""
    rot = quat.identity((num_frames, len(names)))
    half = np.radians(knee_bend_deg) / 2
    for hip, knee, ankle in ((4, 5, 6), (8, 9, 10)):
        rot[:, hip] = quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(-half))
        rot[:, knee] = quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(2 * half))
        rot[:, ankle] = quat.from_axis_angle(np.array([1.0, 0, 0]), np.array(-half))
    local = np.broadcast_to(OFFSETS, (num_frames, len(names), 3)).copy()
    local[:, 0] = [0, 80, 0]
    local[:, 0, 2] += 30.0 * np.arange(num_frames) / FPS
    return Motion(names=names, parents=PARENTS, offsets=OFFSETS, rotations=rot, local_positions=local, fps=FPS,
                  channels=tuple(() for _ in names), end_site_parents=np.zeros(0, dtype=np.int64),
                  end_site_offsets=np.zeros((0, 3)), source=source)


def test_planted_synthetic_feet_stay_put():
    m = _standing(40)
    contacts = np.zeros((40, 2))
    contacts[5:25] = 0.9  # soft labels, thresholded at 0.5
    fixed = footik.fix_foot_sliding(m, contacts, blend_frames=4)
    before, after = js.global_positions(m), js.global_positions(fixed)
    for ankle in (6, 10):
        np.testing.assert_allclose(after[5:25, ankle], np.broadcast_to(before[5, ankle], (20, 3)), atol=1e-9)
        np.testing.assert_array_equal(after[:5, ankle], before[:5, ankle])
        np.testing.assert_array_equal(after[29:, ankle], before[29:, ankle])
    np.testing.assert_array_equal(fixed.rotations[:5], m.rotations[:5])
    np.testing.assert_array_equal(fixed.rotations[29:], m.rotations[29:])
    assert not np.array_equal(fixed.rotations[10], m.rotations[10])
    # a FootContacts is accepted for its foot labels. Straight legs (no knee direction to keep) bend
    # the knee forward (local +Z) when the hips come down nearer the held feet
    labels = js.FootContacts(heel=contacts > 0.5, toe=np.zeros((40, 2), bool))
    straight = _standing(40, knee_bend_deg=0.0)
    local = straight.local_positions.copy()
    local[5:, 0, 1] -= np.arange(35)  # 1 cm down a frame, 0.5 cm forward
    straight = straight.replace(local_positions=local)
    fixed = footik.fix_foot_sliding(straight, labels)
    pos = js.global_positions(fixed)
    np.testing.assert_allclose(pos[5:25, 6], np.broadcast_to(js.global_positions(straight)[5, 6], (20, 3)),
                               atol=1e-9)
    assert np.all(pos[6:25, 5, 2] > (pos[6:25, 4, 2] + pos[6:25, 6, 2]) / 2 + 1.0)
    assert np.isfinite(fixed.rotations).all()


def test_bad_input_is_named():
    m = _standing(10)
    with pytest.raises(ValueError, match="contacts_TxF"):
        footik.fix_foot_sliding(m, np.zeros((10, 3)))
    with pytest.raises(ValueError, match="contacts_TxF"):
        footik.fix_foot_sliding(m, np.zeros((9, 2)))
    with pytest.raises(ValueError, match="blend_frames"):
        footik.fix_foot_sliding(m, np.zeros((10, 2)), blend_frames=-1)
    no_feet = _standing(10, source="no_feet.bvh", names=tuple(f"J{i}" for i in range(len(NAMES))))
    with pytest.raises(ValueError, match="no_feet.bvh"):
        footik.fix_foot_sliding(no_feet, np.zeros((10, 2)))


# --- a real walk ---

def test_fix_foot_sliding_on_a_real_walk(mocap):
    walk = js.read_bvh(mocap / "100style/Neutral/Neutral_FW.bvh").frames(0, 200)
    upm = js.estimate_units_per_meter(walk)
    # the ankle is still while its heel is down: these stand in for the network's predicted labels
    contacts = js.foot_contacts(walk).heel
    local = walk.local_positions.copy()
    local[:, 0, 0] += 0.3 * upm * np.arange(walk.num_frames) / walk.fps  # the root drifts sideways at 0.3 m/s
    drifted = walk.replace(local_positions=local)
    kept = drifted.rotations.copy()
    fixed = footik.fix_foot_sliding(drifted, contacts, blend_frames=5)
    assert isinstance(fixed, Motion) and fixed is not drifted
    np.testing.assert_array_equal(drifted.rotations, kept)  # nothing modified in place

    feet = js.FootJoints.find(walk)
    ankles = list(feet.ankles)
    legs = {j for a in ankles for j in (a, walk.parents[a], walk.parents[walk.parents[a]])}
    g_rot0, g_pos0 = kinematics.global_transforms(drifted)
    g_rot1, g_pos1 = kinematics.global_transforms(fixed)

    def contact_speed(g_pos):
        step = np.linalg.norm(np.diff(g_pos[:, ankles][..., [0, 2]], axis=0), axis=-1) * walk.fps / upm
        return step[contacts[1:] & contacts[:-1]]

    before, after = contact_speed(g_pos0), contact_speed(g_pos1)
    assert before.mean() > 0.25 and after.mean() < 0.02
    assert np.mean(after < 1e-9) > 0.3  # standing still exactly where the leg reaches

    # each contact run holds the ankle where it was at the run's start, wherever the leg reaches
    for side, ankle in enumerate(ankles):
        knee = walk.parents[ankle]
        hip = walk.parents[knee]
        reach = np.linalg.norm(walk.offsets[knee]) + np.linalg.norm(walk.offsets[ankle])
        starts, ends = runs(contacts[:, side])
        for s, e in zip(starts, ends, strict=True):
            held = g_pos0[s, ankle]
            ok = np.linalg.norm(held - g_pos0[s:e, hip], axis=-1) < reach * (1 - 1e-6)
            np.testing.assert_allclose(g_pos1[s:e, ankle][ok], np.broadcast_to(held, (ok.sum(), 3)), atol=1e-9)

    # bones keep their lengths exactly (forward kinematics of the new local rotations)
    child = np.flatnonzero(walk.parents >= 0)
    lengths = np.linalg.norm(g_pos1[:, child] - g_pos1[:, walk.parents[child]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(np.linalg.norm(walk.offsets[child], axis=-1), lengths.shape),
                               atol=1e-9 * upm)
    # joints off the legs are untouched, and so are the legs far from any contact
    others = [j for j in range(walk.num_joints) if j not in legs]
    np.testing.assert_array_equal(fixed.rotations[:, others], drifted.rotations[:, others])
    np.testing.assert_array_equal(fixed.local_positions, drifted.local_positions)
    for side, ankle in enumerate(ankles):
        leg = [ankle, walk.parents[ankle], walk.parents[walk.parents[ankle]]]
        near = np.zeros(walk.num_frames, bool)
        for s, e in zip(*runs(contacts[:, side]), strict=True):
            near[s:e + 5] = True
        assert (~near).sum() > 20
        np.testing.assert_array_equal(fixed.rotations[~near][:, leg], drifted.rotations[~near][:, leg])
    # the ankles keep their global rotations, so the feet keep their orientation
    dots = np.abs(np.sum(g_rot0[:, ankles] * g_rot1[:, ankles], axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(fixed.rotations, axis=-1), 1.0, atol=1e-12)


def test_heel_and_toe_stay_planted_and_blend_smoothly():
    """(T, 4) heel and toe labels: the heel is down for frames 5-24, the toe for 10-29 (the heel
    rolls off first). With ``toe_roll``, while down each stays within 1 mm of where it was held, although the hips
    move on at 0.3 m/s; released, a foot catches up the 10 cm it was held back over the 10 blend
    frames (at most 2.5 cm a frame, where a pop would move it 10 cm at once); bones keep their
    lengths."""
    m = _standing(60)
    labels = np.zeros((60, 4))
    labels[5:25, :2] = 1.0   # heels
    labels[10:30, 2:] = 1.0  # toes
    fixed = footik.fix_foot_sliding(m, labels, blend_frames=10, toe_roll=True)
    before, after = js.global_positions(m), js.global_positions(fixed)
    for ankle, toe in ((6, 7), (10, 11)):
        np.testing.assert_allclose(after[5:25, ankle], np.broadcast_to(after[5, ankle], (20, 3)), atol=0.1)
        np.testing.assert_allclose(after[5, ankle], before[5, ankle], atol=1e-9)
        np.testing.assert_allclose(after[10:30, toe], np.broadcast_to(after[10, toe], (20, 3)), atol=0.1)
        for j in (ankle, toe):
            step = np.linalg.norm(np.diff(after[:, j], axis=0), axis=-1)
            assert step.max() < 2.5, step.max()
        np.testing.assert_array_equal(after[:5, toe], before[:5, toe])
        np.testing.assert_array_equal(after[41:, toe], before[41:, toe])
    child = np.flatnonzero(PARENTS >= 0)
    lengths = np.linalg.norm(after[:, child] - after[:, PARENTS[child]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(np.linalg.norm(OFFSETS[child], axis=-1), lengths.shape),
                               atol=1e-9)
    # without the roll, a toe is held only while its heel is down too (frames 10-24), then released
    flat = js.global_positions(footik.fix_foot_sliding(m, labels, blend_frames=10))
    for ankle, toe in ((6, 7), (10, 11)):
        np.testing.assert_allclose(flat[5:25, ankle], np.broadcast_to(flat[5, ankle], (20, 3)), atol=0.1)
        np.testing.assert_allclose(flat[10:25, toe], np.broadcast_to(flat[10, toe], (15, 3)), atol=0.1)
        assert np.linalg.norm(flat[29, toe] - flat[10, toe]) > 1.0
    # the ankle-only fix (per-foot labels) leaves the toes sliding with the hips
    ankle_only = js.global_positions(footik.fix_foot_sliding(m, labels[:, :2], blend_frames=10))
    assert np.linalg.norm(ankle_only[24, 7] - ankle_only[10, 7]) < 1.0  # heel held: toe held too while flat
    assert np.linalg.norm(ankle_only[29, 7] - ankle_only[25, 7]) > 1.0  # heel released: the toe slides on
