"""Drive styled characters of any :class:`jaxstyle.control.model.CharacterModel` along named paths
in one batched rollout: what the synthesis (:mod:`jaxstyle.output.synthesis`) and the quality
benchmark (:mod:`jaxstyle.output.quality`) share.

Each character starts from a real pose of its own style (:func:`jaxstyle.data.datasets.style_rows`:
a forward walk, else a forward run) chosen to move near the requested speed
(:func:`jaxstyle.control.loop.start_row`), walks each path at that speed (its style's own median
speed by default, :meth:`CharacterModel.own_speed`), follows it with the path-following law
(:func:`jaxstyle.control.loop.follow_gains`), and every (character, path) pair is generated in ONE
jitted, batched ``lax.scan`` (:func:`jaxstyle.control.model.rollout_batch`, the weights shared).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.control import loop, paths
from jaxstyle.control.loop import stack_trees
from jaxstyle.control.model import CharacterModel, rollout_batch
from jaxstyle.data import datasets
from jaxstyle.data.datasets import style_rows


class Character(NamedTuple):
    """One style to drive: its ``title`` (GIF panels, tables), a file-safe ``label``, its style
    ``conditioning`` (what the model's step takes: the 2018 residual adapter, a 2022 FiLM vector,
    one-hot row or adapter), and the ``dataset`` + ``style`` whose rows give its start pose, its
    own speed and its capture."""

    title: str
    label: str
    conditioning: Any
    dataset: datasets.Dataset
    style: str


class Driven(NamedTuple):
    """A batched rollout of characters along paths: ``pairs[k] = (character index, path name)``
    of rollout ``k`` along ``signals[k]`` (:class:`jaxstyle.control.paths.PathSignal`), the model's
    frames with a leading ``len(pairs)`` axis (``rollouts``), each character's walking ``speeds``
    (m/s) and the compiled rollout's wall time ``seconds``."""

    pairs: list[tuple[int, str]]
    signals: list[paths.PathSignal]
    rollouts: Any
    speeds: list[float]
    seconds: float


class Starts(NamedTuple):
    """Per character its start ``states`` and walking ``speeds`` (m/s), :func:`start_states`."""

    states: list
    speeds: list[float]


def start_states(model: CharacterModel, characters: Sequence, units_per_meter: float, fps: float, *,
                 speed: float | None = None) -> Starts:
    """Per character (anything with ``conditioning``, ``dataset`` and ``style``): its walking speed
    (``speed``, or its style's own, :meth:`CharacterModel.own_speed` over
    :func:`jaxstyle.data.datasets.style_rows`) and a start state
    (:meth:`CharacterModel.initial_state`) at a frame of its style moving near that speed
    (:func:`jaxstyle.control.loop.start_row`)."""
    starts, speeds = [], []
    for c in characters:
        rows = style_rows(c.dataset, c.style)
        v = model.own_speed(c.dataset, rows, units_per_meter, fps) if speed is None else float(speed)
        row = loop.start_row(c.dataset.inputs, v, units_per_meter=units_per_meter, rows=rows, fps=fps)
        starts.append(model.initial_state(c.dataset, row, c.conditioning))
        speeds.append(v)
    return Starts(starts, speeds)


def check_paths(path_names: Sequence[str], seconds: float) -> None:
    """Refuse unknown path names (:data:`jaxstyle.control.paths.PATHS`) or a non-positive length."""
    unknown = [p for p in path_names if p not in paths.PATHS]
    if unknown or not path_names:
        raise KeyError(f"unknown path(s) {unknown}; known: {', '.join(paths.PATHS)}")
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds}")


@dataclasses.dataclass(frozen=True)
class Course:
    """Where characters are driven: every path of ``path_names``
    (:data:`jaxstyle.control.paths.PATHS`) for ``seconds``; at ``speed`` m/s (``None``: each
    character at its style's own median speed); ``follow_seconds``, the path-following law's time
    constant (``None``: open loop)."""

    path_names: Sequence[str]
    seconds: float
    speed: float | None = None
    follow_seconds: float | None = loop.FOLLOW_SECONDS


def drive(model: CharacterModel, characters: Sequence, course: Course, *, units_per_meter: float, fps: float,
          timed: bool = False) -> Driven:
    """Every character along every path of the ``course`` (:class:`Course`; see the module
    docstring), in one batched rollout. ``timed``: compile first, then time the compiled rollout
    alone (``Driven.seconds``; NaN otherwise)."""
    if not characters:
        raise ValueError("no characters to drive")
    path_names, seconds, speed, follow_seconds = (course.path_names, course.seconds, course.speed,
                                                  course.follow_seconds)
    check_paths(path_names, seconds)
    starts, speeds = start_states(model, characters, units_per_meter, fps, speed=speed)
    pairs = [(i, p) for i in range(len(characters)) for p in path_names]
    signals = [paths.named(p, seconds, speeds[i], units_per_meter=units_per_meter, fps=fps) for i, p in pairs]
    which = [i for i, _ in pairs]
    args = (model, model.stack_styles([characters[i].conditioning for i in which]),
            stack_trees([starts[i] for i in which]),
            stack_trees([loop.signal_controls(sig, follow_seconds=follow_seconds) for sig in signals]))
    elapsed = float("nan")
    if timed:
        jax.block_until_ready(rollout_batch(*args))  # compile
        t0 = time.perf_counter()
    out = jax.block_until_ready(rollout_batch(*args))
    if timed:
        elapsed = time.perf_counter() - t0
    return Driven(pairs, signals, out, speeds, elapsed)


def blend_character(model: CharacterModel, characters: Sequence[Character], weights: Sequence[float]) -> Character:
    """A character in a blend of 2 or 3 styles with barycentric ``weights``
    (:meth:`CharacterModel.blend_styles`: the 2018 adapters' exact CP blend, the 2022 paper's
    section 4.4 interpolation of FiLM vectors), starting like the first."""
    if len(characters) != len(weights) or not 2 <= len(characters) <= 3:
        raise ValueError(f"a blend takes 2 or 3 styles with one weight each, got {len(characters)} styles and "
                         f"{len(weights)} weights")
    w = [float(x) for x in np.asarray(weights, dtype=np.float64)]
    conditioning = model.blend_styles([c.conditioning for c in characters], np.asarray(weights, dtype=np.float64))
    title = " + ".join(f"{100 * wi:.0f}% {c.label}" for wi, c in zip(w, characters, strict=True))
    label = "blend_" + "_".join(f"{c.label}{round(100 * wi)}" for wi, c in zip(w, characters, strict=True))
    first = characters[0]
    return Character(title, label, conditioning, first.dataset, first.style)
