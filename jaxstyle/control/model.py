"""What a network must provide to be driven as a character: the :class:`CharacterModel` interface,
and the rollouts every model family shares.

Both papers' networks are driven by one closed loop (Holden et al. 2017's runtime, which Mason et
al. 2018 section 7.1 and Mason, Starke & Komura 2022 section 4.4 reuse; :mod:`jaxstyle.control.loop`).
What differs between model families is one frame's step (assemble the input from the carried
state, apply the network with a character's style conditioning, move the character by the
output) and a few facts about their data. A model family implements :class:`CharacterModel` once
(:class:`jaxstyle.control.controller.PFNNModel` for the 2018 PFNN with residual adapters,
:class:`jaxstyle.control.lpn_controller.StyleNetModel` for the 2022 style models); everything above
(:func:`rollout`, :func:`rollout_batch`, :func:`step_fn`, the synthesis of
:mod:`jaxstyle.output.synthesis`, the quality benchmark of :mod:`jaxstyle.output.quality`, the live
session of :mod:`jaxstyle.play`) takes any of them.

An implementation is a pytree (a ``flax.struct.dataclass``): its weights and normalisation
statistics are leaves, so a model is an ordinary argument of a jitted function and the weights are
shared (broadcast) across the characters of :func:`rollout_batch`; what changes the compiled
program (layer sizes, the expert-blend input) is static.

The *style conditioning* of a character (the 2018 residual adapter, a FiLM vector, a one-hot row,
...) is whatever the model's :meth:`CharacterModel.step` takes as ``style``; the model stacks them
(:meth:`CharacterModel.stack_styles`) and blends them (:meth:`CharacterModel.blend_styles`).
"""

from __future__ import annotations

import functools
from typing import Any, Protocol, Sequence, runtime_checkable

import jax
import numpy as np

from jaxstyle.control import loop
from jaxstyle.control.loop import Controls


@runtime_checkable
class Frames(Protocol):
    """What a model's step records per frame (stacked over frames by the loop): at least the
    network's global joint ``positions (T, B, 3)`` (the skeleton's joints first), the ground
    ``origin (T, 2)`` and ``yaw (T,)``, and the de-normalised network ``outputs (T, O)`` as applied;
    and, for one character, how to turn them into what a user gets."""

    positions: Any
    origin: Any
    yaw: Any
    outputs: Any

    def decode(self, skeleton):
        """The :class:`jaxstyle.Motion` of one character's frames on ``skeleton`` (the training
        data's; the character starts at the origin facing +Z)."""

    def predicted_contacts(self, num_joints: int) -> np.ndarray | None:
        """The foot contact labels the network predicted ``(T, 2)`` or ``(T, 4)``, or ``None``."""

    def arrays(self) -> dict[str, Any]:
        """The arrays to save beside the BVH (:func:`jaxstyle.output.export.save_rollout`)."""


@runtime_checkable
class CharacterModel(Protocol):
    """One network family as the closed loop needs it (see the module docstring). Methods, all pure:

    * ``step(style, state, control) -> (state, frame)``: one frame. ``control`` is one row of
      :class:`jaxstyle.control.loop.Controls` already steered toward the path
      (:func:`jaxstyle.control.loop.steer`: ``(offsets (6, 2), yaw (6,), stand ())``); ``state`` a
      pytree with the ground history ``hist_xz (61, 2)`` (the last row is the character's origin);
      ``frame`` one frame of a :class:`Frames`.
    * ``initial_state(dataset, row, style) -> state``: the loop's start at a real frame ``row`` of
      the model's training ``dataset`` (:class:`jaxstyle.data.datasets.Dataset`), for a character of
      that style conditioning.
    * ``own_speed(dataset, rows, units_per_meter, fps) -> float``: the median ground speed (m/s) of
      the data ``rows`` (read off the outputs of the model's feature layout).
    * ``stack_styles(styles) -> stacked``: per-character style conditionings stacked on a leading
      axis (what :func:`rollout_batch` takes).
    * ``blend_styles(styles, weights) -> style``: one conditioning for a blend of styles with
      barycentric ``weights``.
    """

    def step(self, style, state, control): ...

    def initial_state(self, dataset, row: int, style): ...

    def own_speed(self, dataset, rows: np.ndarray, units_per_meter: float, fps: float = 60.0) -> float: ...

    def stack_styles(self, styles: Sequence): ...

    def blend_styles(self, styles: Sequence, weights) -> Any: ...


@jax.jit
def rollout(model: CharacterModel, style, state, controls: Controls):
    """Generate ``T = len(controls.offsets)`` frames of one character closed-loop (one jitted
    ``lax.scan``, :func:`jaxstyle.control.loop.scan_frames`): ``style`` is its conditioning,
    ``state`` its start (:meth:`CharacterModel.initial_state`). Returns the model's
    :class:`Frames`, stacked over ``T``."""
    return loop.scan_frames(model.step, style, state, controls)


@functools.partial(jax.jit, static_argnames=("shared_style",))
def rollout_batch(model: CharacterModel, styles, states, controls: Controls, *, shared_style: bool = False):
    """:func:`rollout` for ``C`` characters at once (``vmap`` over characters,
    :func:`jaxstyle.control.loop.scan_characters`): ``states`` and ``controls`` stacked on a leading
    axis (:func:`jaxstyle.control.loop.stack_trees`), ``styles`` too (:meth:`CharacterModel.stack_styles`), or one
    conditioning for all with ``shared_style`` (e.g. ``None``, the 2018 base without an adapter).
    The model's weights are shared. Every field of the result has a leading ``C`` axis."""
    return loop.scan_characters(model.step, styles, states, controls, shared_style=shared_style)


def step_fn(model: CharacterModel, default_style):
    """A jitted ``f(state, control, style=default_style) -> (state, frame)`` that generates ONE
    frame, the runtime's call per displayed frame when a user steers live
    (:func:`jaxstyle.control.loop.live_step`). The model's weights are compiled in as constants, as
    a game runtime loads them once: that halves the per-frame cost at batch 1 against passing ~20
    weight arrays every call (``benchmarks/runtime.py``). The style stays an argument, so it can be
    switched or blended live (a conditioning of the same shapes compiles once)."""
    return loop.live_step(model.step, default_style)


def batched_step_fn(model: CharacterModel):
    """A jitted ``f(styles, states, controls) -> (states, frames)`` that advances ``C`` characters by
    one frame (``jit(vmap(step))``, every argument with a leading character axis; the control rows
    already steered, ``(offsets (C, 6, 2), yaw (C, 6), stand (C,))``): the live session's call per
    displayed frame for several characters. The weights are compiled in as constants
    (:func:`step_fn`)."""
    return jax.jit(jax.vmap(model.step))
