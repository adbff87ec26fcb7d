"""One live frame for many characters: the steering rows of every character at once and one jitted
program that advances all of them (network step, foot locking, what the scene draws).

A session keeps its characters in **slots**: a leading axis whose size is a power of two
(:func:`slots_for`), the characters in the first slots and copies of the start state in the rest.
The program is compiled once per slot count, so adding or removing a character within the slots
compiles nothing, and a style switch or blend changes only array values (the runtime styles are
an argument). One call per frame returns, on the host, everything the scene and the recording
need: the network outputs, the (locked) joint positions, each character's ground position and
facing, and its predicted future trajectory in the world.

Units: the program works in the skeleton's file units, as the network does; the session turns
them into metres.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES
from jaxstyle.output import footlock

ARRIVE_M = 0.3  # a waypoint is reached within this distance
SAMPLE_SECONDS = np.arange(FUTURE_SAMPLES) * loop.SPACING / 60.0  # the future samples' times, 0 .. 50 frames
MODES = ("stop", "target", "direction")


@dataclasses.dataclass
class Steering:
    """How one character is steered: ``mode`` ``stop``, ``target`` (walk through ``waypoints``, x z
    in metres, then stop) or ``direction`` (walk along ``heading``); at ``speed`` m/s."""

    mode: str = "stop"
    waypoints: list[tuple[float, float]] = dataclasses.field(default_factory=list)
    heading: float = 0.0
    speed: float = 1.0


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def control_rows(origin_Cx2: np.ndarray, yaw_C: np.ndarray, steerings: Sequence[Steering],
                 units_per_meter: float) -> tuple[np.ndarray, np.ndarray]:
    """The rows of :class:`jaxstyle.control.loop.Controls` for ``C`` characters at ``origin_Cx2``
    (x, z in metres) facing ``yaw_C``: ``offsets (C, 6, 2)`` (global ground displacement to the
    future samples, file units) and ``yaw (C, 6)``. Towards a target the displacement grows at the
    steering's speed and stops at the target; the facing turns to the direction of travel (the
    shorter way round); standing still keeps the current facing. A reached waypoint (within
    :data:`ARRIVE_M`) is dropped from its steering; the last one reached stops the character."""
    origin = np.asarray(origin_Cx2, np.float64).reshape(-1, 2)
    yaw = np.asarray(yaw_C, np.float64).reshape(-1)
    n = len(steerings)
    goal = np.zeros((n, 2))
    for i, s in enumerate(steerings):  # drop reached waypoints (rarely more than a distance test)
        if s.mode != "target":
            continue
        while s.waypoints and math.dist(s.waypoints[0], origin[i]) <= ARRIVE_M:
            s.waypoints.pop(0)
        if not s.waypoints:
            s.mode = "stop"
        else:
            goal[i] = s.waypoints[0]
    mode = np.array([MODES.index(s.mode) for s in steerings])
    speed = np.array([s.speed for s in steerings], np.float64)
    heading = np.array([s.heading for s in steerings], np.float64)
    target, direction = mode == 1, mode == 2
    d = goal - origin
    dist = np.where(target, np.hypot(d[:, 0], d[:, 1]), 1.0)
    unit = np.where(target[:, None], d / np.maximum(dist, 1e-12)[:, None],
                    np.stack([np.sin(heading), np.cos(heading)], axis=-1))
    reach = speed[:, None] * SAMPLE_SECONDS[None]
    reach = np.where(target[:, None], np.minimum(reach, dist[:, None]), reach)
    offsets = np.where((target | direction)[:, None, None], reach[:, :, None] * unit[:, None, :], 0.0)
    wanted = np.where(target, np.arctan2(d[:, 0], d[:, 1]), heading)
    facing = np.where(target | direction, yaw + _wrap(wanted - yaw), yaw)
    return offsets * units_per_meter, np.repeat(facing[:, None], FUTURE_SAMPLES, axis=1)


def control_row(origin_m: np.ndarray, yaw: float, steering: Steering, units_per_meter: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`control_rows` of one character: ``offsets (6, 2)`` and ``yaw (6,)``."""
    offsets, facing = control_rows(np.asarray(origin_m)[None], np.array([yaw]), [steering], units_per_meter)
    return offsets[0], facing[0]


def slots_for(count: int) -> int:
    """The slot count for ``count`` characters: the next power of two (1, 2, 4, 8, ...)."""
    return 1 << max(0, int(count) - 1).bit_length()


class FrameOut(NamedTuple):
    """One frame of every slot, in file units: the network's per-character ``out`` (a
    :class:`~jaxstyle.control.controller.Rollout` or
    :class:`~jaxstyle.control.lpn_controller.LPNRollout` row per slot), the skeleton's joint
    ``positions (S, J, 3)`` (feet locked when locking is on), ground ``origin (S, 2)``, ``yaw
    (S,)`` and the predicted future trajectory in the world ``future (S, 6, 2)`` (x, z)."""

    out: Any
    positions: jax.Array
    origin: jax.Array
    yaw: jax.Array
    future: jax.Array


def labels_of(out, columns: np.ndarray | None) -> jax.Array:
    """``(S, 2, 2)`` contact labels ``[side, heel/toe]`` per slot (the array form of
    :func:`jaxstyle.output.footlock.labels_per_point`): an LPN's two foot labels (heel and toe share
    one), the 2018 layout's heel and toe outputs at ``columns``
    (:func:`jaxstyle.data.pfnn_features.contact_columns`), zeros when the model predicts none."""
    contacts = getattr(out, "contacts", None)
    if contacts is not None:
        return jnp.repeat(contacts[:, :, None], 2, axis=2).astype(jnp.float32)
    if columns is None:
        return jnp.zeros((out.positions.shape[0], 2, 2), jnp.float32)
    c = out.outputs[:, columns]
    return jnp.stack([c[:, :2], c[:, 2:]], axis=2).astype(jnp.float32)


_PROGRAMS: dict = {}


def frame_program(step: Callable, skeleton, num_joints: int, columns: np.ndarray | None,
                  config: footlock.FootLockConfig | None = None):
    """The jitted ``f(runtimes, states, lock_states, (offsets, yaw, stand), lock) -> (states,
    lock_states, FrameOut)`` for a model's batched ``step`` (``jit(vmap(model step))`` over slots):
    the step, then, when the boolean array ``lock`` is true, the feet of every slot locked for the
    frame (``vmap`` of :func:`jaxstyle.output.footlock.position_step` with the network's labels,
    :func:`labels_of`; the lock states stay as they were while it is false), and the frame's
    ground positions and world-space future. Built once per step, skeleton and lock setting."""
    key = (id(step), skeleton.names, float(skeleton.fps), num_joints,
           None if columns is None else tuple(int(c) for c in columns), config)
    if key in _PROGRAMS and _PROGRAMS[key][0] is step:
        return _PROGRAMS[key][1]
    rig = footlock.leg_rig(skeleton)
    params = footlock.params_for(skeleton, config)

    def lock_one(state, pos, labels):
        state, out, _ = footlock.position_step(params, rig, state, pos, labels)
        return state, out

    def program(runtimes, states, lock_states, controls, lock):
        states, out = step(runtimes, states, controls)
        positions = out.positions[:, :num_joints]
        lock_states, positions = jax.lax.cond(
            lock, lambda: jax.vmap(lock_one)(lock_states, positions, labels_of(out, columns)),
            lambda: (lock_states, positions))
        origin, yaw = states.hist_xz[:, -1], states.hist_yaw[:, -1]
        fx, fz = loop.rotate_xz(states.future[:, 0], states.future[:, 1], yaw[:, None])
        future = jnp.stack([fx + origin[:, :1], fz + origin[:, 1:]], axis=-1)
        return states, lock_states, FrameOut(out, positions, origin, yaw, future)

    compiled = jax.jit(program)
    _PROGRAMS[key] = (step, compiled)
    return compiled


def init_lock_states(slots: int) -> footlock.LockState:
    """``slots`` foot-lock states before their first frame."""
    return jax.tree.map(lambda v: jnp.broadcast_to(v, (slots,) + v.shape), footlock.init_state())
