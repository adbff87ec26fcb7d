"""Foot locking: feet that stay planted, decided from the generated motion, held by leg IK, released smoothly.

Every runtime of these papers post-processes the network's pose with foot IK (Mason, Starke &
Komura 2022 section 4.4: "foot contact inverse kinematics" with the predicted contact labels; the
authors' Unity demos and AI4Animation do the same). This module is that post-process, causal (each
frame decided from the past only, so :mod:`jaxstyle.play` runs it live) and batched (one
``lax.scan`` over frames, ``vmap`` over characters).

Per foot there are two contact points, the heel (the ankle joint) and the toe (the toe joint):

1. **Contacts from the motion itself** (:func:`contact_step`). A point touches down when it is
   within ``height_on_m`` of its floor height and slower than ``speed_on_m_s`` (horizontal, over
   the last frame) for ``min_on_s``; a network's predicted contact label can start a contact at a
   higher speed (``label_speed_on_m_s``) but never keeps one: the contact ends when the point is
   higher than ``height_off_m`` or faster than ``speed_off_m_s`` (hysteresis: on and off thresholds
   apart). Metres and seconds are those of a body the size of the 100STYLE actor
   (:func:`jaxstyle.labels.contacts.body_units_per_meter`, leg length based), so the rule is the
   same on any skeleton, in any unit, at any frame rate.
2. **Locks.** At a contact's onset the point's drawn ground position is locked in the world; its
   height stays the network's (raised to the floor where it is below), so a heel that peels off
   the floor at the end of a stance rises as captured instead of being held down. The ankle goes
   to the heel's lock; while only the toe is locked (the heel rolls off) the foot turns about the
   held toe, the ankle one foot length from it towards the network's ankle (toe roll); the toe is
   turned onto its lock while the heel is down, and the two locks are kept one foot length apart
   (the foot is rigid). A lock is on a leash of ``leash_m``: a network point that slides farther
   drags its lock along (no lock-release-relock cycles, no pop back later). A lock is let go when
   its point lifts or speeds up (above) or when the leg cannot reach it (the hip-ankle distance
   would exceed the legs' length by more than ``reach_slack_m``; the heel is let go first, the
   toe can still pivot): no leg is overstretched or pointed backwards to hold a foot. A point that
   was let go locks again only once it is drawn close to the network's point
   (``relock_fraction`` of the leash).
3. **Release without a pop.** Every change of what holds a point (release, heel to toe) is
   absorbed into an offset, position and velocity, that then decays with a critically damped
   spring of half-life ``halflife_s`` (inertialization), so the drawn foot neither jumps nor
   changes speed abruptly (a touch-down stops the point at once, as a real foot stops); the
   spring's own correction is capped at ``max_correction_speed_m_s``, so a foot never catches up
   faster than that on top of the network's motion; no point is ever drawn more than
   ``max_offset_m`` from the network's; a toe nothing holds stays within 0.3 foot lengths of the
   network's foot direction from the drawn ankle.
4. **Leg IK** (:func:`two_bone_positions`, and for BVH export the rotation form
   :func:`jaxstyle.output.footik.two_bone_ik`): analytic hip-knee-ankle, the knee in the plane of
   the network's knee, never straighter than the bones allow.

Defaults: the blend half-life is that of Holden's Motion-Matching demo (0.1 s). Its 0.2 m unlock
radius becomes a 0.12 m leash and a 0.13 m cap, so no foot is drawn more than 0.15 m from where
the network put it; its 1.5 cm leg-length buffer becomes a reach slack of 0 (100STYLE's actor
walks with the stance leg within 1 mm of straight, so a lock must be allowed at full extension,
and beyond it the heel gives way to the toe pivot). The contact thresholds were chosen on the
paper-size models of ``experiments/quality.py`` and a real Neutral walk (``docs/quality.md``).

:func:`lock_sequence` runs the scan; :func:`lock_motion` locks a :class:`jaxstyle.Motion`
(rotations rewritten, bone lengths exact: what the BVH export writes); :func:`lock_positions`
locks joint positions (the live page, previews); :func:`detect_contacts` is the contact rule
alone (the ``steps_per_s`` metric uses it).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.labels.contacts import FLOOR_PERCENTILE, FootJoints, body_units_per_meter, floor_heights
from jaxstyle.motion import Motion, kinematics, quat
from jaxstyle.motion.kinematics import UP_AXIS
from jaxstyle.output import footik

_GROUND = np.array([1.0 if a != UP_AXIS else 0.0 for a in range(3)], dtype=np.float32)


@dataclasses.dataclass(frozen=True)
class FootLockConfig:
    """Thresholds of :mod:`jaxstyle.output.footlock` in metres of a 100STYLE-sized body and seconds
    (see the module docstring for what each does)."""

    height_on_m: float = 0.015
    height_off_m: float = 0.02
    speed_on_m_s: float = 0.4
    label_speed_on_m_s: float = 0.6
    speed_off_m_s: float = 0.7
    min_on_s: float = 1.0 / 30.0
    min_off_s: float = 0.1
    leash_m: float = 0.12
    relock_fraction: float = 0.25
    max_offset_m: float = 0.13
    halflife_s: float = 0.1
    max_correction_speed_m_s: float = 1.5
    reach_slack_m: float = 0.0
    use_labels: bool = True

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name != "use_labels" and not (np.isfinite(v) and v >= 0):
                raise ValueError(f"FootLockConfig.{f.name} must be a finite non-negative number, got {v}")
        if self.height_off_m < self.height_on_m or self.speed_off_m_s < max(self.speed_on_m_s,
                                                                             self.label_speed_on_m_s):
            raise ValueError("FootLockConfig: the off thresholds must not be below the on thresholds")


class LockParams(NamedTuple):
    """A :class:`FootLockConfig` in file units and frames, plus the floor: arrays, so the scan
    compiles once for any skeleton size or setting. ``floor_2x2``: height of each point when
    planted, ``[side, heel/toe]``."""

    height_on: jax.Array
    height_off: jax.Array
    speed_on: jax.Array
    label_speed_on: jax.Array
    speed_off: jax.Array
    min_on: jax.Array
    min_off: jax.Array
    leash: jax.Array
    relock_radius: jax.Array
    max_offset: jax.Array
    damping: jax.Array
    max_step: jax.Array
    reach_slack: jax.Array
    use_labels: jax.Array
    fps: jax.Array
    floor_2x2: jax.Array


def lock_params(config: FootLockConfig, *, units_per_meter: float, fps: float, floor_2x2) -> LockParams:
    """:class:`LockParams` for a body of ``units_per_meter`` (file units per body metre, see
    :func:`jaxstyle.labels.contacts.body_units_per_meter`) at ``fps``; ``floor_2x2``: the planted
    height of heel and toe of each side (``[[heel L, toe L], [heel R, toe R]]``, file units)."""
    u, f = float(units_per_meter), float(fps)
    if not (np.isfinite(u) and u > 0 and np.isfinite(f) and f > 0):
        raise ValueError(f"units_per_meter and fps must be positive, got {units_per_meter} and {fps}")
    floor = np.asarray(floor_2x2, dtype=np.float32)
    if floor.shape != (2, 2) or not np.isfinite(floor).all():
        raise ValueError(f"floor_2x2 must be 2 x 2 finite heights (side x heel/toe), got {floor.shape}")
    c = config
    a = functools.partial(jnp.asarray, dtype=jnp.float32)
    return LockParams(
        height_on=a(c.height_on_m * u), height_off=a(c.height_off_m * u), speed_on=a(c.speed_on_m_s * u),
        label_speed_on=a(c.label_speed_on_m_s * u), speed_off=a(c.speed_off_m_s * u),
        min_on=jnp.asarray(max(1, int(round(c.min_on_s * f))), jnp.int32),
        min_off=jnp.asarray(int(round(c.min_off_s * f)), jnp.int32),
        leash=a(c.leash_m * u), relock_radius=a(c.relock_fraction * c.leash_m * u),
        max_offset=a(c.max_offset_m * u),
        damping=a(0.0 if c.halflife_s == 0 else 2.0 * np.log(2.0) / c.halflife_s),  # y of a critical damper
        max_step=a(c.max_correction_speed_m_s * u / f), reach_slack=a(c.reach_slack_m * u),
        use_labels=a(float(c.use_labels)), fps=a(f), floor_2x2=jnp.asarray(floor))


class LockState(NamedTuple):
    """What the scan carries per character, ``[side, heel/toe]`` on the leading axes:
    ``contact`` (the rule's contact state), ``run`` (frames the touch-down test has held),
    ``rest`` (frames since the last contact ended),
    ``locked``, ``lock`` (world position of each lock), ``offset`` / ``offset_velocity`` (the
    decaying inertialization offset per point), ``previous`` (the network's point last frame),
    ``started`` (a frame has been seen)."""

    contact: jax.Array
    run: jax.Array
    rest: jax.Array
    locked: jax.Array
    lock: jax.Array
    offset: jax.Array
    offset_velocity: jax.Array
    previous: jax.Array
    started: jax.Array


def init_state() -> LockState:
    """The state before the first frame (nothing locked)."""
    z = jnp.zeros((2, 2, 3), jnp.float32)
    return LockState(jnp.zeros((2, 2), bool), jnp.zeros((2, 2), jnp.int32), jnp.full((2, 2), 1 << 20, jnp.int32),
                     jnp.zeros((2, 2), bool), z, z, z, z, jnp.asarray(False))


class LockFrame(NamedTuple):
    """One frame's result: the ``ankle`` and ``toe`` positions ``(2, 3)`` to draw (left, right),
    the rule's ``contact`` and the ``locked`` flags ``(2, 2)`` (side x heel/toe)."""

    ankle: jax.Array
    toe: jax.Array
    contact: jax.Array
    locked: jax.Array


def _norm(v):
    return jnp.sqrt(jnp.sum(v * v, axis=-1) + 1e-20)


def _horizontal(v):
    return v * _GROUND


def damper(offset, velocity, damping, dt):
    """One step of a critically damped spring towards zero (exact solution over ``dt``):
    ``j1 = v + y x``, ``x' = e^{-y dt} (x + j1 dt)``, ``v' = e^{-y dt} (v - y j1 dt)``, ``y`` half the
    stiffness-matched damping (``2 ln 2 / half-life``)."""
    j1 = velocity + damping * offset
    e = jnp.exp(-damping * dt)
    return e * (offset + j1 * dt), e * (velocity - damping * j1 * dt)


def contact_step(params: LockParams, state: LockState, net_2x2x3, labels_2x2):
    """The contact rule for one frame: ``(contact, run, rest, touch_down, lift_off, speed)`` per point.

    ``touch_down``: the point is within ``height_on`` of its floor and slower than ``speed_on``
    (or labelled in contact by the network and slower than ``label_speed_on``); ``lift_off``:
    higher than ``height_off`` or faster than ``speed_off``. ``run`` counts the frames
    ``touch_down`` has held; a contact starts when it reaches ``min_on`` (and at least ``min_off``
    frames after the point's last contact ended: no flicker) and ends at ``lift_off``.
    Speeds are horizontal, over the last frame (0 on the first)."""
    height = net_2x2x3[..., UP_AXIS] - params.floor_2x2
    speed = jnp.where(state.started, _norm(_horizontal(net_2x2x3 - state.previous)) * params.fps, 0.0)
    labelled = (labels_2x2 >= 0.5) & (params.use_labels > 0.5)
    down = (height < params.height_on) & ((speed < params.speed_on) | (labelled & (speed < params.label_speed_on)))
    lift = (height > params.height_off) | (speed > params.speed_off)
    run = jnp.where(down, state.run + 1, 0)
    contact = jnp.where(state.contact, ~lift, (run >= params.min_on) & ~lift & (state.rest >= params.min_off))
    rest = jnp.where(contact, 0, jnp.minimum(state.rest, 1 << 20) + 1)
    return contact, run, rest, down, lift, speed


def _targets(locked, lock, net):
    """Offsets ``(2, 2, 3)`` (drawn minus network, per point, on the ground plane: a lock holds a
    point's ground position, its height stays the network's) that the locks ask for, and which
    lock each point follows (0 heel, 1 toe, 2 none): the ankle holds the heel's lock, else turns
    about the toe's lock (toe roll: one foot length from it, towards the network's ankle), else is
    free; the toe holds its lock, else moves with the ankle."""
    heel_l, toe_l = locked[:, 0, None], locked[:, 1, None]
    heel_off = _horizontal(lock[:, 0] - net[:, 0])
    toe_off = _horizontal(lock[:, 1] - net[:, 1])
    # toe roll: the ankle one foot length from the held toe, towards the network's ankle (the
    # nearest such point to it, so the leg reaches it whenever it reaches the network's ankle)
    toe_at = net[:, 1] + toe_off
    foot = net[:, 0] - toe_at
    rolled = toe_at + foot * (_norm(net[:, 0] - net[:, 1]) / _norm(foot))[:, None] - net[:, 0]
    ankle = jnp.where(heel_l, heel_off, jnp.where(toe_l, rolled, 0.0))
    ankle_src = jnp.where(heel_l[:, 0], 0, jnp.where(toe_l[:, 0], 1, 2))  # 0 heel, 1 toe, 2 free
    toe = jnp.where(toe_l, toe_off, ankle)
    toe_src = jnp.where(toe_l[:, 0], 1, ankle_src)
    return jnp.stack([ankle, toe], axis=1), jnp.stack([ankle_src, toe_src], axis=1)


def _target_velocity(src, net_velocity):
    """Rate of change of :func:`_targets`' offsets: minus the ground velocity of the network's point
    that each point's lock holds against (0 for a free point)."""
    heel, toe = net_velocity[:, 0][:, None], net_velocity[:, 1][:, None]
    return jnp.where((src == 0)[..., None], -heel, jnp.where((src == 1)[..., None], -toe, 0.0))


def lock_step(params: LockParams, state: LockState, net_2x2x3, labels_2x2, hip_2x3, leg_length_2):
    """One causal frame of foot locking.

    Args:
      params: :func:`lock_params`.
      state: the previous frame's :class:`LockState` (:func:`init_state` before the first).
      net_2x2x3: the network's heel (ankle joint) and toe positions, ``[side, heel/toe]``.
      labels_2x2: the network's contact labels per point (values >= 0.5 mean contact); zeros when
        the model predicts none.
      hip_2x3, leg_length_2: each leg's hip position and thigh + shin length (the reach test).

    Returns the new state and the :class:`LockFrame` to draw.
    """
    net = jnp.asarray(net_2x2x3, jnp.float32)
    dt = 1.0 / params.fps
    contact, run, rest, _, _, _ = contact_step(params, state, net, labels_2x2)
    # the decaying offsets, one spring step, the correction speed capped
    offset, velocity = damper(state.offset, state.offset_velocity, params.damping, dt)
    change = offset - state.offset
    scale = jnp.minimum(1.0, params.max_step / _norm(change))[..., None]
    offset = state.offset + change * scale
    velocity = velocity * scale
    # a lock is on a leash: the network's point never gets farther than ``leash`` from it (a foot
    # the network slides further drags its lock along instead of popping back later)
    away = _horizontal(state.lock - net)
    leashed = state.lock - away * (1.0 - jnp.minimum(1.0, params.leash / _norm(away)))[..., None]
    old_target, old_src = _targets(state.locked, leashed, net)
    drawn = net + old_target + offset  # where each point is drawn if nothing changes
    keep = state.locked & contact
    start = ~state.locked & contact & (_norm(offset + old_target) <= params.relock_radius)
    # a new lock sits where the point is drawn now, not below the floor
    new_lock = drawn.at[..., UP_AXIS].set(jnp.maximum(drawn[..., UP_AXIS], params.floor_2x2))
    lock = jnp.where(start[..., None], new_lock, leashed)
    locked = keep | start
    # heel and toe both held: the toe's lock stays one foot length from the heel's (the foot is
    # rigid), so the toe is drawn on its lock and the heel can roll off about it without a jump
    heel_at = net[:, 0] + _horizontal(lock[:, 0] - net[:, 0])
    toe_at = net[:, 1] + _horizontal(lock[:, 1] - net[:, 1])
    arm = toe_at - heel_at
    up = arm[:, UP_AXIS:UP_AXIS + 1]
    length = _norm(net[:, 1] - net[:, 0])[:, None]
    flat = _horizontal(arm)
    reach_flat = jnp.sqrt(jnp.maximum(length * length - up * up, 0.0))
    rigid = heel_at + flat * (reach_flat / _norm(flat)[:, None])
    both = (locked[:, 0] & locked[:, 1])[:, None]
    lock = lock.at[:, 1].set(jnp.where(both, rigid + (lock[:, 1] - toe_at), lock[:, 1]))
    # a leg that cannot reach its ankle's target lets its points go
    # where the ankle goes once the offsets have decayed: at most reach_slack beyond the legs' reach
    # (the heel first: with the toe still held the foot can pivot about it, then the toe)
    def reachable(held):
        target, _ = _targets(held, lock, net)
        return _norm(net[:, 0] + target[:, 0] - hip_2x3) <= leg_length_2 + params.reach_slack

    locked = locked.at[:, 0].set(locked[:, 0] & reachable(locked))
    locked = locked & reachable(locked)[:, None]
    target, src = _targets(locked, lock, net)
    # inertialization: what the change of holder moved, the offset takes over and lets decay
    offset = offset + old_target - target
    # ... and the velocity: a released point leaves with the velocity it was drawn with (zero), and
    # the spring eases it into the network's (no kink; a lock lets go below speed_off, so the drawn
    # foot trails the network's by about speed_off / (e * damping), ~2 cm); a point that has just
    # touched down stops where it is, as a real foot does.
    net_velocity = jnp.where(state.started, _horizontal(net - state.previous) * params.fps, 0.0)
    fresh = ((src == 0) & start[:, :1]) | ((src == 1) & start[:, 1:])
    velocity = jnp.where(fresh[..., None], 0.0, velocity + _target_velocity(old_src, net_velocity)
                         - _target_velocity(src, net_velocity))
    # a toe held alone is the foot's pivot: the drawn ankle (still easing in) is put back at one
    # foot length from it, so the easing never drags the held toe; the correction joins the
    # ankle's offset, so it eases out too when the toe lets go
    out = net + target + offset
    pivot = (locked[:, 1] & ~locked[:, 0])[:, None]
    toe_at = out[:, 1].at[:, UP_AXIS].set(jnp.maximum(out[:, 1, UP_AXIS], params.floor_2x2[:, 1]))
    arm = out[:, 0] - toe_at
    rolled = toe_at + arm * (_norm(net[:, 0] - net[:, 1]) / _norm(arm))[:, None]
    offset = offset.at[:, 0].add(jnp.where(pivot, rolled - out[:, 0], 0.0))
    # no point is ever drawn more than max_offset from the network's (lock and easing together)
    moved = target + offset
    offset = moved * jnp.minimum(1.0, params.max_offset / _norm(moved))[..., None] - target
    out = net + target + offset
    # a toe nothing holds stays near the network's foot direction from the drawn ankle (what it
    # still has to ease back is at most 0.3 foot lengths), so a foot never turns round
    foot = net[:, 1] - net[:, 0]
    bend = out[:, 1] - out[:, 0] - foot
    limit = 0.3 * _norm(foot)
    bent = out[:, 0] + foot + bend * jnp.minimum(1.0, limit / _norm(bend))[:, None]
    out = out.at[:, 1].set(jnp.where(locked[:, 1:], out[:, 1], bent))
    offset = offset.at[:, 1].set(out[:, 1] - net[:, 1] - target[:, 1])
    out = out.at[..., UP_AXIS].set(jnp.maximum(out[..., UP_AXIS], params.floor_2x2))
    new_state = LockState(contact, run, rest, locked, lock, offset, velocity, net, jnp.asarray(True))
    return new_state, LockFrame(out[:, 0], out[:, 1], contact, locked)


class LegRig(NamedTuple):
    """Joint indices of both legs, left then right: ``hip``, ``knee``, ``ankle``, ``toe``, and per
    side the joints below the ankle (toe included) that move with the foot, ``foot_joints``."""

    hip: tuple[int, int]
    knee: tuple[int, int]
    ankle: tuple[int, int]
    toe: tuple[int, int]
    foot_joints: tuple[tuple[int, ...], tuple[int, ...]]


def leg_rig(skeleton: Motion, feet: FootJoints | None = None) -> LegRig:
    """The :class:`LegRig` of a skeleton (feet found by name unless given)."""
    feet = feet or FootJoints.find(skeleton)
    chains = footik._leg_chains(skeleton, feet)  # the same leg chains and error messages
    parents = np.asarray(skeleton.parents)
    below = []
    for _, _, ankle in chains:
        inside = {ankle}
        for j in range(len(parents)):
            if parents[j] in inside:
                inside.add(j)
        below.append(tuple(sorted(inside - {ankle})))
    return LegRig(tuple(c[0] for c in chains), tuple(c[1] for c in chains), tuple(c[2] for c in chains),
                  tuple(int(t) for t in feet.toes), (below[0], below[1]))


def rig_points(rig: LegRig, positions_JxD) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(net (2, 2, 3), hip (2, 3), leg length (2,))`` of one frame's joint positions."""
    p = jnp.asarray(positions_JxD, jnp.float32)
    hip, knee, ankle, toe = (p[jnp.asarray(idx)] for idx in (rig.hip, rig.knee, rig.ankle, rig.toe))
    return jnp.stack([ankle, toe], axis=1), hip, _norm(knee - hip) + _norm(ankle - knee)


def lock_sequence(params: LockParams, rig: LegRig, positions_TxJx3, labels_Tx2x2=None,
                  state: LockState | None = None) -> tuple[LockState, LockFrame]:
    """:func:`lock_step` over every frame of ``positions_TxJx3`` (global, file units) in one
    ``lax.scan``; ``labels_Tx2x2`` the network's contacts per point (``None``: none). Returns the
    final state and the per-frame :class:`LockFrame` (leading axis frames). ``vmap`` it over
    characters for a batch."""
    pos = jnp.asarray(positions_TxJx3, jnp.float32)
    labels = jnp.zeros((pos.shape[0], 2, 2), jnp.float32) if labels_Tx2x2 is None else jnp.asarray(labels_Tx2x2,
                                                                                                     jnp.float32)

    def body(s, frame):
        p, lab = frame
        net, hip, length = rig_points(rig, p)
        return lock_step(params, s, net, lab, hip, length)

    return jax.lax.scan(body, init_state() if state is None else state, (pos, labels))


_lock_sequence_jit = jax.jit(lock_sequence, static_argnums=1)


def labels_per_point(contacts) -> np.ndarray | None:
    """A network's contact labels as ``(T, 2, 2)`` ``[side, heel/toe]``: ``(T, 4)`` heel L, heel R,
    toe L, toe R (the 2018 layout's outputs) or ``(T, 2)`` per foot (the LPN's; heel and toe
    share it); ``None`` stays ``None``."""
    if contacts is None:
        return None
    c = np.asarray(contacts, dtype=np.float32)
    if c.ndim != 2 or c.shape[1] not in (2, 4):
        raise ValueError(f"contact labels must be (T, 2) per foot or (T, 4) heel L, heel R, toe L, toe R; "
                         f"got {c.shape}")
    if not np.isfinite(c).all():
        raise ValueError("contact labels contain NaN or infinity")
    if c.shape[1] == 2:
        return np.repeat(c[:, :, None], 2, axis=2)
    return np.stack([c[:, :2], c[:, 2:]], axis=2)


def skeleton_floor(motion: Motion, feet: FootJoints | None = None) -> np.ndarray:
    """``(2, 2)`` planted height of heel and toe per side (file units): the
    :data:`~jaxstyle.labels.contacts.FLOOR_PERCENTILE` th percentile of each joint's height over
    ``motion`` (a clip of the skeleton, e.g. the training data's)."""
    feet = feet or FootJoints.find(motion)
    pos = kinematics.global_positions(motion)
    joints = [feet.ankles[0], feet.toes[0], feet.ankles[1], feet.toes[1]]
    return floor_heights(pos[:, joints, UP_AXIS], FLOOR_PERCENTILE).reshape(2, 2)


def params_for(skeleton: Motion, config: FootLockConfig | None = None, *, fps: float | None = None,
               floor_2x2=None, feet: FootJoints | None = None) -> LockParams:
    """:func:`lock_params` for ``skeleton`` (a clip of it: its leg length sets the units, its own
    feet the floor unless ``floor_2x2`` is given)."""
    feet = feet or FootJoints.find(skeleton)
    floor = skeleton_floor(skeleton, feet) if floor_2x2 is None else floor_2x2
    return lock_params(config or FootLockConfig(), units_per_meter=body_units_per_meter(skeleton, feet),
                       fps=float(fps or skeleton.fps), floor_2x2=floor)


class LockedMotion(NamedTuple):
    """:func:`lock_motion`'s result: the locked ``motion``, the per-frame ``frames``
    (:class:`LockFrame` as NumPy), and ``offset_max`` (the largest distance, file units, a foot
    joint was moved)."""

    motion: Motion
    frames: LockFrame
    offset_max: float


def _foot_direction(xp, foot, to_target):
    """The direction to turn a foot (ankle-to-toe vector ``foot``) so its toe lands at the target's
    height: ``to_target`` with its ground part rescaled so its length is the foot's (the target's
    own direction where the foot cannot reach that height). NumPy or JAX (``xp``)."""
    length2 = xp.sum(foot * foot, axis=-1, keepdims=True)
    up = to_target[..., UP_AXIS:UP_AXIS + 1]
    ground = to_target * _GROUND
    g2 = xp.sum(ground * ground, axis=-1, keepdims=True)
    scale = xp.sqrt(xp.maximum(length2 - up * up, 0.0) / xp.maximum(g2, 1e-12))
    ok = (length2 > up * up) & (g2 > 1e-12)
    return xp.where(ok, ground * scale + to_target * (1.0 - _GROUND), to_target)


def _rotate_onto(g_rot, g_pos, motion: Motion, rotations, rig: LegRig, ankle_Tx2x3, toe_Tx2x3) -> None:
    """Rewrite hip, knee and ankle local rotations (in place) so each ankle lands on its target
    and each foot points at its toe target; frames where both already hold are left bit for bit."""
    for side in range(2):
        hip, knee, ankle, toe = rig.hip[side], rig.knee[side], rig.ankle[side], rig.toe[side]
        moved = np.linalg.norm(ankle_Tx2x3[:, side] - g_pos[:, ankle], axis=-1) > 1e-6
        turned = np.linalg.norm(toe_Tx2x3[:, side] - g_pos[:, toe], axis=-1) > 1e-6
        idx = np.flatnonzero(moved | turned)
        if idx.size == 0:
            continue
        pole = footik._knee_poles(g_rot[:, knee], g_pos[:, hip], g_pos[:, knee], g_pos[:, ankle])[idx]
        ik = footik.two_bone_ik(g_pos[idx, hip], g_pos[idx, knee], g_pos[idx, ankle], ankle_Tx2x3[idx, side], pole)
        hip_global = quat.mul(ik.hip_rotation, g_rot[idx, hip])
        knee_global = quat.mul(ik.knee_rotation, g_rot[idx, knee])
        # the foot: translated with the ankle, then turned (shortest arc) so the toe points at its target
        toe_now = ik.ankle + (g_pos[idx, toe] - g_pos[idx, ankle])
        arm = toe_now - ik.ankle
        swing = quat.between(arm, _foot_direction(np, arm, toe_Tx2x3[idx, side] - ik.ankle))
        ankle_global = quat.mul(swing, g_rot[idx, ankle])
        above = int(motion.parents[hip])
        hip_local = hip_global if above < 0 else quat.mul(quat.inverse(g_rot[idx, above]), hip_global)
        new = {hip: hip_local, knee: quat.mul(quat.inverse(hip_global), knee_global),
               ankle: quat.mul(quat.inverse(knee_global), ankle_global)}
        for joint, local in new.items():
            rotations[idx, joint] = footik._same_hemisphere(local, motion.rotations[idx, joint])


def lock_motion(motion: Motion, contacts=None, *, config: FootLockConfig | None = None, floor_2x2=None,
                feet: FootJoints | None = None) -> LockedMotion:
    """Lock the feet of a :class:`Motion` (e.g. decoded from a network's output) and return the
    result with the rotations rewritten (bone lengths exact).

    Args:
      contacts: the network's contact labels, ``(T, 4)`` heel L, heel R, toe L, toe R or ``(T, 2)``
        per foot (:func:`labels_per_point`), or ``None`` (the motion alone decides).
      config: :class:`FootLockConfig` (defaults).
      floor_2x2: planted heights ``[side, heel/toe]``; the motion's own when omitted (its 5th
        height percentile: fine offline; live, pass the training skeleton's, :func:`skeleton_floor`).
      feet: ankle and toe joints, found by name when omitted.
    """
    rig = leg_rig(motion, feet)
    feet = feet or FootJoints.find(motion)
    params = params_for(motion, config, floor_2x2=floor_2x2, feet=feet)
    g_rot, g_pos = kinematics.global_transforms(motion)
    labels = labels_per_point(contacts)
    if labels is not None and len(labels) != motion.num_frames:
        raise ValueError(f"contacts have {len(labels)} frames, the motion {motion.num_frames}")
    _, frames = _lock_sequence_jit(params, rig, g_pos, labels)
    frames = jax.tree.map(lambda v: np.asarray(v, dtype=np.float64) if v.dtype != bool else np.asarray(v), frames)
    rotations = np.array(motion.rotations, dtype=np.float64, copy=True)
    _rotate_onto(g_rot, g_pos, motion, rotations, rig, frames.ankle, frames.toe)
    out = motion.replace(rotations=rotations)
    after = kinematics.global_positions(out)
    joints = list(rig.ankle) + list(rig.toe)
    moved = float(np.max(np.linalg.norm(after[:, joints] - g_pos[:, joints], axis=-1))) if len(after) else 0.0
    return LockedMotion(out, frames, moved)


# --- positions (live page, previews) -------------------------------------------------------------------------------

def two_bone_positions(hip, knee, ankle, target, forward):
    """New ``(knee, ankle)`` of a hip-knee-ankle chain whose ankle goes to ``target`` (analytic,
    the bone lengths of the given pose, the distance clamped to what the bones reach), the knee
    in the plane of the old knee (``forward``, e.g. the foot's direction, where the leg is
    straight). Any leading axes; JAX."""
    l1, l2 = _norm(knee - hip), _norm(ankle - knee)
    to_target = target - hip
    dist = _norm(to_target)
    u = to_target / dist[..., None]
    d = jnp.clip(dist, jnp.abs(l1 - l2) + 1e-6, l1 + l2)
    side = (knee - hip) - jnp.sum((knee - hip) * u, axis=-1, keepdims=True) * u
    fwd = forward - jnp.sum(forward * u, axis=-1, keepdims=True) * u
    bent = _norm(side) > 1e-3 * l1
    side = jnp.where(bent[..., None], side, fwd)
    n = side / _norm(side)[..., None]
    cos = jnp.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    sin = jnp.sqrt(jnp.maximum(1.0 - cos * cos, 0.0))
    new_knee = hip + l1[..., None] * (cos[..., None] * u + sin[..., None] * n)
    return new_knee, hip + d[..., None] * u


def _rotation_between(a, b):
    """``(3, 3)`` rotation taking direction ``a`` to direction ``b`` (Rodrigues; identity for equal)."""
    a = a / _norm(a)
    b = b / _norm(b)
    v = jnp.cross(a, b)
    c = jnp.sum(a * b)
    k = jnp.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return jnp.eye(3) + k + k @ k / (1.0 + jnp.maximum(c, -1.0 + 1e-6))


def apply_to_positions(rig: LegRig, positions_JxD, frame: LockFrame):
    """One frame's joint positions with the legs moved to the :class:`LockFrame`: knee and ankle by
    :func:`two_bone_positions`, the foot's joints turned (toe onto its target) and carried with
    the ankle. JAX; ``vmap`` over characters."""
    p = jnp.asarray(positions_JxD, jnp.float32)
    for side in range(2):
        hip, knee, ankle, toe = p[rig.hip[side]], p[rig.knee[side]], p[rig.ankle[side]], p[rig.toe[side]]
        new_knee, new_ankle = two_bone_positions(hip, knee, ankle, frame.ankle[side], toe - ankle)
        turn = _rotation_between(toe - ankle, _foot_direction(jnp, toe - ankle, frame.toe[side] - new_ankle))
        foot = jnp.asarray(rig.foot_joints[side])
        p = p.at[foot].set(new_ankle + (p[foot] - ankle) @ turn.T)
        p = p.at[rig.knee[side]].set(new_knee).at[rig.ankle[side]].set(new_ankle)
    return p


def position_step(params: LockParams, rig: LegRig, state: LockState, positions_JxD, labels_2x2=None):
    """One live frame: :func:`lock_step` on the joint positions, then :func:`apply_to_positions`.
    Returns the new state, the locked positions and the :class:`LockFrame`."""
    p = jnp.asarray(positions_JxD, jnp.float32)
    net, hip, length = rig_points(rig, p)
    labels = jnp.zeros((2, 2), jnp.float32) if labels_2x2 is None else labels_2x2
    state, frame = lock_step(params, state, net, labels, hip, length)
    return state, apply_to_positions(rig, p, frame), frame


def lock_positions(params: LockParams, rig: LegRig, positions_TxJx3, labels_Tx2x2=None) -> tuple[np.ndarray,
                                                                                                   LockFrame]:
    """Locked joint positions ``(T, J, 3)`` of a whole sequence (the network's joints, e.g. for a
    preview) and the per-frame :class:`LockFrame`: :func:`position_step` in one scan."""
    pos = jnp.asarray(positions_TxJx3, jnp.float32)
    labels = jnp.zeros((pos.shape[0], 2, 2), jnp.float32) if labels_Tx2x2 is None else jnp.asarray(labels_Tx2x2,
                                                                                                     jnp.float32)

    def body(s, frame):
        s, p, f = position_step(params, rig, s, *frame)
        return s, (p, f)

    _, (out, frames) = jax.lax.scan(body, init_state(), (pos, labels))
    return np.asarray(out), jax.tree.map(np.asarray, frames)


# --- the contact rule alone (metrics) ------------------------------------------------------------------------------

@jax.jit
def _detect(params: LockParams, points_Tx2x2x3):
    def body(s, net):
        contact, run, rest, _, _, _ = contact_step(params, s, net, jnp.zeros((2, 2)))
        return s._replace(contact=contact, run=run, rest=rest, previous=net, started=jnp.asarray(True)), contact

    return jax.lax.scan(body, init_state(), jnp.asarray(points_Tx2x2x3, jnp.float32))[1]


def detect_contacts(points_Tx2x2x3, *, units_per_meter: float, fps: float, floor_2x2,
                    config: FootLockConfig | None = None) -> np.ndarray:
    """``(T, 2, 2)`` contacts ``[side, heel/toe]`` of heel and toe positions by the rule of
    :func:`contact_step` (the network's labels not used), in file units with ``units_per_meter``
    body units per metre."""
    params = lock_params(config or FootLockConfig(), units_per_meter=units_per_meter, fps=fps, floor_2x2=floor_2x2)
    return np.asarray(_detect(params, points_Tx2x2x3))


def points_of(positions_TxJx3, feet: FootJoints) -> np.ndarray:
    """``(T, 2, 2, 3)`` heel (ankle) and toe positions per side from joint positions."""
    pos = np.asarray(positions_TxJx3)
    return np.stack([pos[:, list(feet.ankles)], pos[:, list(feet.toes)]], axis=2)


__all__: Sequence[str] = (
    "FootLockConfig", "LockParams", "LockState", "LockFrame", "LegRig", "LockedMotion", "lock_params", "params_for",
    "init_state", "contact_step", "lock_step", "lock_sequence", "lock_motion", "leg_rig", "labels_per_point",
    "skeleton_floor", "two_bone_positions", "apply_to_positions", "position_step", "lock_positions",
    "detect_contacts", "points_of", "damper")
