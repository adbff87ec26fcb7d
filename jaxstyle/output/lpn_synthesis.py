"""Drive characters of the 2022 style models along user paths: GIF, BVH and quality figures.

The runtime of Mason, Starke & Komura 2022 section 4.4 (a style model in the closed loop of
:mod:`jaxstyle.control.lpn_controller`, the style a precomputed FiLM vector, a one-hot row or an
adapter) for several (style, path) characters at once, in ONE batched, jitted ``lax.scan``
(:func:`jaxstyle.control.lpn_controller.rollout_batch`, the network's weights broadcast). Each
character starts from a real pose of its own style chosen to match the requested speed, with that
frame's local and global phases (the global phase drives Table 2's PFNN-backbone models, and
advances at the rate :func:`jaxstyle.control.lpn_controller.phase_ratio` fits for the character's
style and runtime style on its training rows: :mod:`jaxstyle.control.lpn_controller`). What is
written, and the quality table, are exactly those of the 2018 path
(:func:`jaxstyle.output.synthesis.write_results`: the same :mod:`jaxstyle.output.metrics` functions
on the skeleton's joints, the same GIF, BVH and ``quality.csv``).

Style blends (section 4.4's interpolation of 2-3 styles with barycentric weights): FiLM vectors are
blended linearly (:func:`jaxstyle.nn.film_generator.interpolate`), as are one-hot rows and LPN/MANN
adapters (:func:`jaxstyle.nn.style_models.blend_styles`); see :func:`blend_character`.

Used by :mod:`jaxstyle.mason2022.synthesis` (``jaxstyle synthesize --model lpn-film``, ``jaxstyle
demo --model lpn-film``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop, lpn_controller, paths
from jaxstyle.data import datasets
from jaxstyle.data.lpn_features import LPNLayout, end_effector_columns
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import FUTURE_SAMPLES
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.nn import style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output.synthesis import SynthesisResult, stack_trees, start_states, style_rows, write_results


class LPNCharacter(NamedTuple):
    """One style to drive with a 2022 model: its ``title`` (GIF panels, tables), a file-safe
    ``label``, its runtime ``runtime`` style (a FiLM vector ``(4 H,)``, a one-hot row or an adapter:
    what :func:`jaxstyle.nn.style_models.model_apply` takes), and the LPN ``dataset`` + ``style``
    whose rows give its start pose (with its local phases) and its own speed."""

    title: str
    label: str
    runtime: Any
    dataset: datasets.Dataset
    style: str


def own_speed(dataset: datasets.Dataset, rows: np.ndarray, units_per_meter: float, fps: float = 60.0) -> float:
    """The median ground speed (m/s) over LPN ``rows``: the first output trajectory sample is the
    next frame's ground position in the current frame (:mod:`jaxstyle.data.lpn_features`)."""
    y = dataset.outputs[rows]
    return float(np.median(np.hypot(y[:, 0], y[:, FUTURE_SAMPLES])) * fps / units_per_meter)


def start_state(dataset: datasets.Dataset, row: int, num_bones: int, ratio: float = 1.0) -> lpn_controller.LPNState:
    """The 2022 controller's start at LPN ``row`` of ``dataset``: its input, local phases and global
    phase, with the global phase's ``ratio`` to the predicted local advance
    (:func:`jaxstyle.control.lpn_controller.phase_ratio`). A dataset without global phases (a cache
    older than them) starts at phase 0, which only the PFNN backbone reads."""
    phase = float(dataset.global_phase[row]) if len(dataset.global_phase) == len(dataset.inputs) else 0.0
    return lpn_controller.initial_state(dataset.inputs[row], dataset.phases[row], num_bones, phase, ratio)


def style_phase_ratio(params: dict, config: StyleModelConfig, runtime, normalisers: tuple[Normaliser, Normaliser],
                      dataset: datasets.Dataset, style: str, *, gate_columns=None) -> float:
    """The global-phase rate a character of ``style`` (its rows in ``dataset``) with the runtime
    style ``runtime`` starts with: :func:`jaxstyle.control.lpn_controller.phase_ratio` on the
    style's rows for Table 2's PFNN backbone, 1 for the LPN and MANN backbones, which do not read
    the global phase. :func:`synthesize`, the quality benchmark and ``jaxstyle play`` use it."""
    if config.backbone != "pfnn":
        return 1.0
    x_norm, y_norm = normalisers
    return float(lpn_controller.phase_ratio(params, config, runtime, x_norm, y_norm, dataset,
                                            style_rows(dataset, style), gate_columns=gate_columns))


def blend_character(config: StyleModelConfig, characters: Sequence[LPNCharacter], weights: Sequence[float]
                    ) -> LPNCharacter:
    """A character in a blend of 2 or 3 styles with barycentric ``weights`` (non-negative, summing
    to 1; section 4.4): the blended runtime style (:func:`jaxstyle.nn.style_models.blend_styles`:
    for FiLM the weighted sum of the styles' FiLM vectors), starting like the first. Weights
    ``(1, 0, ...)`` give the first style's runtime style exactly."""
    if len(characters) != len(weights) or not 2 <= len(characters) <= 3:
        raise ValueError(f"a blend takes 2 or 3 styles with one weight each, got {len(characters)} styles and "
                         f"{len(weights)} weights")
    stacked = stack_trees([c.runtime for c in characters])
    runtime = style_models.blend_styles(config, stacked, jnp.asarray(weights, jnp.float32))
    w = [float(x) for x in weights]
    title = " + ".join(f"{100 * wi:.0f}% {c.label}" for wi, c in zip(w, characters, strict=True))
    label = "blend_" + "_".join(f"{c.label}{round(100 * wi)}" for wi, c in zip(w, characters, strict=True))
    first = characters[0]
    return LPNCharacter(title, label, runtime, first.dataset, first.style)


def synthesize(params: dict, config: StyleModelConfig, normalisers: tuple[Normaliser, Normaliser],
               characters: Sequence[LPNCharacter], skeleton: Motion, out: str | Path, *,
               path_names: Sequence[str] = ("circle",), seconds: float = 8.0, speed: float | None = None,
               foot_lock: bool = True, gif: bool = True, mp4: bool = False, every: int = 2,
               contact_sheet: bool = False, reference: bool = True, progress: bool = False) -> SynthesisResult:
    """Drive every character along every path with a 2022 style model and write the results under
    ``out``: the 2018 :func:`jaxstyle.output.synthesis.synthesize` for the 2022 models (LPN, MANN and
    PFNN backbones).

    Args:
      params, config: the trained style model (:func:`jaxstyle.nn.style_models.init_model`'s tree).
      normalisers: the training data's (input, output) statistics (new styles' rows are normalised
        with them too, as in training).
      characters: :class:`LPNCharacter` s (runtime styles of one kind, e.g. all FiLM vectors).
      skeleton: a clip of the training skeleton (bone lengths, fps, units; the MANN's gating columns).
      Other arguments as :func:`jaxstyle.output.synthesis.synthesize`; ``foot_lock`` locks the feet
      with the network's own predicted contacts.
    """
    if not characters:
        raise ValueError("no characters to drive")
    unknown = [p for p in path_names if p not in paths.PATHS]
    if unknown or not path_names:
        raise KeyError(f"unknown path(s) {unknown}; known: {', '.join(paths.PATHS)}")
    if seconds <= 0:
        raise ValueError(f"seconds must be positive, got {seconds}")
    x_norm, y_norm = normalisers
    upm = estimate_units_per_meter(skeleton)
    fps = skeleton.fps
    num_bones = (len(x_norm.mean) - 48) // 12  # checked against the model just below
    if LPNLayout(num_bones).input_size != config.input_size:
        raise ValueError(f"the normalisers have {len(x_norm.mean)} inputs, the model {config.input_size}")
    gate_columns = end_effector_columns(skeleton) if config.backbone == "mann" else None
    starts, speeds = start_states(characters, upm, fps, lambda c, ds, row: start_state(
        ds, row, num_bones, style_phase_ratio(params, config, c.runtime, (x_norm, y_norm), ds, c.style,
                                              gate_columns=gate_columns)), speed=speed, speed_of=own_speed)
    pairs = [(s, p) for s in range(len(characters)) for p in path_names]
    signals = [paths.named(p, seconds, speeds[s], units_per_meter=upm, fps=fps) for s, p in pairs]
    args = (params, config, stack_trees([characters[s].runtime for s, _ in pairs]), x_norm, y_norm,
            stack_trees([starts[s] for s, _ in pairs]), stack_trees([loop.signal_controls(sig) for sig in signals]))
    jax.block_until_ready(lpn_controller.rollout_batch(*args, gate_columns=gate_columns))  # compile
    t0 = time.perf_counter()
    rollouts = jax.block_until_ready(lpn_controller.rollout_batch(*args, gate_columns=gate_columns))
    elapsed = time.perf_counter() - t0
    rows, files = write_results(out, characters, pairs, signals, rollouts, skeleton, foot_lock=foot_lock, gif=gif,
                                mp4=mp4, every=every, contact_sheet=contact_sheet, reference=reference,
                                progress=progress)
    return SynthesisResult(rows, files, elapsed, len(pairs) * int(rollouts.positions.shape[1]),
                           dict(zip([c.title for c in characters], speeds, strict=True)))
