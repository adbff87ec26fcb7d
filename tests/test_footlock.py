"""Foot locking (jaxstyle.output.footlock): held feet, bounded releases, reach, toe roll, causal == batched."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.labels.contacts import body_units_per_meter
from jaxstyle.motion import Motion, quat
from jaxstyle.output import footlock, metrics
from tests.synthetic_legs import NAMES, OFFSETS, PARENTS

FPS = 60.0
X = np.array([1.0, 0.0, 0.0])


def _walker(knee_deg: np.ndarray, root_z_cm: np.ndarray) -> Motion:
    """The synthetic legs (cm) with per-frame knee bends (the thigh swings forward by half of it,
    so the foot rises and moves under the hip) and a root moving along +Z."""
    n = len(knee_deg)
    rot = quat.identity((n, len(NAMES)))
    half = np.radians(knee_deg) / 2
    for hip, knee, ankle in ((4, 5, 6), (8, 9, 10)):
        rot[:, hip] = quat.from_axis_angle(X, -half)
        rot[:, knee] = quat.from_axis_angle(X, 2 * half)
        rot[:, ankle] = quat.from_axis_angle(X, -half)
    local = np.broadcast_to(OFFSETS, (n, len(NAMES), 3)).copy()
    local[:, 0] = [0, 80, 0]
    local[:, 0, 2] += root_z_cm
    return Motion(names=NAMES, parents=PARENTS, offsets=OFFSETS, rotations=rot, local_positions=local, fps=FPS,
                  channels=tuple(() for _ in NAMES), end_site_parents=np.zeros(0, dtype=np.int64),
                  end_site_offsets=np.zeros((0, 3)), source="synthetic.bvh")


def test_a_sliding_foot_is_held_within_a_millimetre_and_released_at_a_bounded_speed():
    """The network's feet slide at 0.3 m/s for 0.3 s on the floor, then lift (the knee bends to 90
    degrees). Locked, the exported ankle stays within 1 mm of where it touched down; released, the
    foot rejoins the network's at no more than the configured correction speed on top of it."""
    n = 60
    knee = np.r_[np.full(20, 30.0), np.linspace(30.0, 90.0, 40)]
    m = _walker(knee, 30.0 * np.arange(n) / FPS)
    config = footlock.FootLockConfig()
    out = footlock.lock_motion(m, config=config)
    before, after = js.global_positions(m), js.global_positions(out.motion)
    upm = body_units_per_meter(m)
    for ankle in (6, 10):
        held = after[3:20, ankle]  # touched down after min_on frames
        assert np.linalg.norm(held - held[0], axis=-1).max() < 0.1, "held within 1 mm (0.1 cm)"
        assert np.linalg.norm(before[19, ankle] - before[3, ankle]) > 7.0  # the network's foot slid 8 cm
        offset = after[:, ankle] - before[:, ankle]
        correction = np.linalg.norm(np.diff(offset, axis=0), axis=-1) * FPS / upm
        assert correction.max() <= config.max_correction_speed_m_s + 1e-3, correction.max()
        assert np.linalg.norm(offset[-1]) < 0.5  # back with the network's foot by the end
    assert out.frames.locked[5:19].all() and not out.frames.locked[-1].any()


def test_a_lock_that_would_need_a_metre_of_reach_is_released_and_the_leg_never_bends_backwards():
    """The feet slide at 0.3 m/s for 4 s with the knees barely bent: holding them would need over
    1 m of reach. The locks are let go as soon as the leg cannot reach them (a held foot is never
    farther than its leash from the network's either), no foot is moved more than 0.15 m,
    and each knee stays bent forward (on the network's side of the hip-ankle line), never past straight."""
    n = 240
    m = _walker(np.full(n, 4.0), 30.0 * np.arange(n) / FPS)
    labels = np.ones((n, 4))  # the network insists the feet are planted all along
    out = footlock.lock_motion(m, labels)
    before, after = js.global_positions(m), js.global_positions(out.motion)
    upm = body_units_per_meter(m)
    assert out.offset_max / upm <= 0.15
    for hip, knee, ankle in ((4, 5, 6), (8, 9, 10)):
        axis = after[:, ankle] - after[:, hip]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        side = (after[:, knee] - after[:, hip]) - np.sum((after[:, knee] - after[:, hip]) * axis, -1)[:, None] * axis
        assert (side[:, 2] >= -1e-6).all(), "the knee points forward (+Z) or the leg is straight"
        length = np.linalg.norm(after[:, ankle] - after[:, hip], axis=-1)
        assert (length <= 80.0 + 1e-6).all()
        leg_before = before[:, ankle] - before[:, hip]
        cos = np.sum(axis * leg_before, -1) / np.linalg.norm(leg_before, axis=-1)
        assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 12.0  # never swung back behind the hip
    # a held foot is dragged on a leash: never farther from the network's than the leash
    leash = footlock.FootLockConfig().leash_m * upm
    for ankle in (6, 10):
        ground = np.linalg.norm((after[:, ankle] - before[:, ankle])[:, [0, 2]], axis=-1)
        assert ground.max() <= leash + 0.05, ground.max()
    # with the legs this straight, a lock falls out of reach as soon as the hips move on: let go
    # (heels; a toe may still pivot, the ankle one foot length from it, within the leg's reach)
    assert out.frames.locked[:, :, 0].mean() < 0.2 and out.frames.contact.mean() > 0.9


def test_out_of_reach_locks_are_released_at_once():
    params = footlock.lock_params(footlock.FootLockConfig(), units_per_meter=100.0, fps=FPS,
                                  floor_2x2=np.zeros((2, 2)))
    state = footlock.init_state()
    net = jnp.zeros((2, 2, 3)).at[:, 1, 2].set(15.0)
    hip = jnp.array([[0.0, 80.0, 0.0], [0.0, 80.0, 0.0]])
    for _ in range(3):  # touch down
        state, frame = footlock.lock_step(params, state, net, jnp.zeros((2, 2)), hip, jnp.full(2, 90.0))
    assert bool(frame.locked.all())
    far = jnp.array([[0.0, 80.0, 100.0], [0.0, 80.0, 100.0]])  # the hips 1 m ahead: the lock needs 1.28 m of leg
    state, frame = footlock.lock_step(params, state, net, jnp.zeros((2, 2)), far, jnp.full(2, 90.0))
    assert not bool(frame.locked[:, 0].any())


def test_the_live_per_frame_path_equals_the_batched_scan_and_vmap_equals_a_loop(mocap):
    m = js.read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh").frames(0, 150)
    rig, params = footlock.leg_rig(m), footlock.params_for(m)
    pos = js.global_positions(m).astype(np.float32)
    batched, frames = footlock.lock_positions(params, rig, pos)
    step = jax.jit(lambda s, p: footlock.position_step(params, rig, s, p))
    state = footlock.init_state()
    for t in range(len(pos)):
        state, live, _ = step(state, pos[t])
        np.testing.assert_allclose(np.asarray(live), batched[t], atol=1e-3)
    # the rotation form (BVH export) puts the ankles where the scan said
    locked = footlock.lock_motion(m, floor_2x2=np.asarray(params.floor_2x2))
    np.testing.assert_allclose(locked.frames.ankle, frames.ankle, atol=1e-3)
    # two characters at once (vmap) == each alone
    two = np.stack([pos, pos[::-1].copy()])
    vm = jax.vmap(lambda p: footlock.lock_sequence(params, rig, p)[1].ankle)(jnp.asarray(two))
    for i in range(2):
        np.testing.assert_allclose(np.asarray(vm[i]), np.asarray(footlock.lock_sequence(params, rig, two[i])[1].ankle),
                                   atol=1e-4)


def test_real_capture_is_barely_changed_and_the_toe_is_held_while_the_heel_rolls_off(mocap):
    """On a real walk the lock holds what the capture holds: skating rises by under 0.01 m/s, no
    foot moves more than the 0.12 m leash; while only a toe is locked (the heel peeling off) the exported toe's
    ground position stays within 1.5 cm (median 1 mm), although the heel rises."""
    m = js.read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh")
    out = footlock.lock_motion(m)
    before, after = js.global_positions(m), js.global_positions(out.motion)
    skate = [metrics.foot_skating(p, m, m.fps, units_per_meter=100.0) for p in (before, after)]
    assert skate[1] <= skate[0] + 0.01, skate
    assert out.offset_max < 12.0  # the leash
    feet = js.FootJoints.find(m)
    drifts, rises = [], []
    for side in range(2):
        roll = out.frames.locked[:, side, 1] & ~out.frames.locked[:, side, 0]
        toe, ankle = feet.toes[side], feet.ankles[side]
        for s in np.flatnonzero(np.diff(roll.astype(int)) == 1) + 1:
            e = s + int(np.argmin(roll[s:])) if not roll[s:].all() else len(roll)
            if e - s >= 5:
                ground = after[s:e, toe][:, [0, 2]]
                drifts.append(np.linalg.norm(ground - ground[0], axis=-1).max())
                rises.append(after[e - 1, ankle, 1] - after[s, ankle, 1])
    # the held toe moves by a millimetre (median; up to 1.5 cm where the extended push-off leg cannot quite reach)
    assert len(drifts) >= 10 and np.median(drifts) < 0.3 and max(drifts) < 1.5, drifts
    assert np.median(rises) > 2.0  # while the heel rose (cm)


def test_step_figures_cannot_be_passed_by_frozen_or_gliding_feet(mocap):
    m = js.read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh").frames(0, 600)
    pos = js.global_positions(m)
    real = metrics.step_figures(pos, m, m.fps)
    assert 1.0 < real.steps_per_s < 2.5 and 0.45 < real.stance_fraction < 0.8
    frozen = np.broadcast_to(pos[:1], pos.shape).copy()  # feet (and everything) frozen
    f = metrics.step_figures(frozen, m, m.fps)
    assert f.steps_per_s == 0.0 and f.stance_fraction == 1.0
    glide = np.broadcast_to(pos[:1], pos.shape).copy()
    glide[..., 2] += 150.0 * np.arange(len(pos))[:, None] / m.fps  # the frozen pose slides at 1.5 m/s
    g = metrics.step_figures(glide, m, m.fps)
    assert g.steps_per_s == 0.0 and g.stance_fraction == 0.0
    assert f.lifted_steps_per_s == 0.0 and g.lifted_steps_per_s == 0.0
    # in real walking every counted onset ends a lift of the foot
    assert real.lifted_steps_per_s <= real.steps_per_s and real.lifted_steps_per_s >= 0.9 * real.steps_per_s


@pytest.mark.parametrize("lift_cm, lifted", [(0.0, 0), (5.0, 1)])
def test_a_foot_that_slides_out_of_contact_on_the_floor_is_not_a_lifted_step(mocap, lift_cm, lifted):
    m = js.read_bvh(mocap / "100style" / "Neutral" / "Neutral_FW.bvh").frames(0, 240)
    pos = np.broadcast_to(js.global_positions(m)[:1], (240, m.num_joints, 3)).copy()  # a still stance
    feet = metrics.FootJoints.find(m)
    foot = [feet.ankles[0], feet.toes[0]]
    # frames 100-119: one foot moves 1.5 m/s forward (faster than the release speed), raised by lift_cm, then stands
    ramp = np.clip(np.arange(240) - 100, 0, 20)
    pos[:, foot, 2] += (150.0 / m.fps * ramp)[:, None]
    pos[100:120, foot, 1] += lift_cm * np.sin(np.pi * np.arange(20) / 19)[:, None] ** 0.25
    figs = metrics.step_figures(pos, m, m.fps, floor_2x2=footlock.skeleton_floor(m))
    assert figs.steps_per_s * m.duration == pytest.approx(1.0)  # one contact onset either way
    assert figs.lifted_steps_per_s * m.duration == pytest.approx(lifted)


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="halflife_s"):
        footlock.FootLockConfig(halflife_s=float("nan"))
    with pytest.raises(ValueError, match="off thresholds"):
        footlock.FootLockConfig(speed_off_m_s=0.1)
    with pytest.raises(ValueError, match="contact labels"):
        footlock.labels_per_point(np.zeros((5, 3)))
