"""The motion-quality benchmark of ``experiments/quality.py``: every character along the
six protocol paths, measured as the user sees it, beside the same figures of its style's capture.

Per (character, path), from ONE batched closed-loop rollout with the path-following law of
:mod:`jaxstyle.control.loop` (:func:`run`, for any :class:`jaxstyle.control.model.CharacterModel`:
the 2018 PFNN with style adapters, the 2022 style models; measured by the one function
:func:`jaxstyle.output.measure.measure`):

* foot skating (:func:`jaxstyle.output.metrics.foot_skating`) of the network's own joints, of the
  exported skeleton (the BVH's forward kinematics: bone lengths exact, :mod:`jaxstyle.output.export`)
  and of the exported skeleton after foot locking (:func:`jaxstyle.output.export.lock_feet`, what
  the BVH holds: contacts from the motion, started also by the network's predicted labels);
* stepping after locking (steps per second, stance fraction, slide per contact:
  :func:`jaxstyle.output.metrics.step_figures`), the largest distance the lock moved a foot and
  how deep a foot goes below the floor (:data:`jaxstyle.output.measure.LOCK_FIGURES`);
* feet on the floor, bone error of the network's joints and of the BVH (0 by construction), and
  the largest distance between the network's joints and the BVH's;
* path error (mean, final, final as % of the path's length), heading error, the time to stop
  after each stop command (:func:`jaxstyle.output.metrics.stop_times`), jitter and ankle jerk.

:func:`capture_row` gives the same figures for a forward clip of the style's capture
(:func:`capture_spec`, loaded once by :class:`CaptureStyle`; no path: those are blank). Every row names its ``model``
(:data:`MODEL_2018` or the 2022 model's Table 2 name).
:mod:`jaxstyle.output.report` checks the targets on the rows and reports them (table, CSV, bars).
:func:`jaxstyle.output.diagnose.diagnose` measures where
sliding and drift come from (teacher-forced vs closed loop, root vs planted-foot velocity, phase
advance vs cadence, trajectory blending, normalisation) for ``docs/quality.md``.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import numpy as np

from jaxstyle.control import loop, paths
from jaxstyle.control.model import CharacterModel
from jaxstyle.data import datasets
from jaxstyle.data.datasets import style_rows
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.motion.kinematics import global_positions
from jaxstyle.output import drive, footlock, metrics, style
from jaxstyle.output.drive import Character
from jaxstyle.output.measure import capture_figures, exported, measure

PROTOCOL_PATHS = ("straight", "circle", "zigzag", "stop_and_go", "speed_ramp", "waypoints")
FOLLOW_PATHS = ("straight", "circle", "zigzag")  # the paths of the 0.3 m final-error target
TARGET_PATHS = FOLLOW_PATHS + ("stop_and_go",)  # the paths of the path and stop targets (``jaxstyle demo``)
PATH_TARGETS = ("final path error <= 0.3 m", "stop within 0.5 s")  # their names in report.targets
SECONDS = 8.0
MODEL_2018 = "2018 PFNN"
"""The ``model`` of the 2018 characters' rows (the 2022 models' rows carry their Table 2 names)."""


@dataclasses.dataclass(frozen=True)
class Subject:
    """One character: ``title``, ``kind`` (``"base"`` or ``"few-shot"``), its style ``conditioning``
    (what its model's step takes: the 2018 PFNN's residual adapter, a 2022 model's FiLM vector,
    one-hot row or adapter), the ``dataset`` + ``style`` whose rows give its start pose, its own
    speed and its capture, and the name of the ``model`` it belongs to."""

    title: str
    kind: str
    conditioning: Any
    dataset: datasets.Dataset
    style: str
    model: str = MODEL_2018


def subject(character: Character, kind: str, model: str = MODEL_2018) -> Subject:
    """The :class:`Subject` of a synthesis :class:`jaxstyle.output.drive.Character`."""
    return Subject(character.title, kind, character.conditioning, character.dataset, character.style, model)


Drawn = dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]


class Measured(NamedTuple):
    """The benchmark's ``rows`` (one per (character, path), then one per capture) and, per ``(title,
    path)``, what is ``drawn``: the exported skeleton's joint positions and the path's ideal positions."""

    rows: list[dict]
    drawn: Drawn


def measure_rollouts(subjects: Sequence[Subject], pairs: Sequence[tuple[int, str]], signals: Sequence[paths.PathSignal],
                     rollouts, skeleton: Motion, speeds: Sequence[float]
                     ) -> Measured:
    """:func:`measure` each rollout of a batch of any model (leading axis ``len(pairs)``,
    ``pairs[k] = (subject index, path name)`` along ``signals[k]``), then one :func:`capture_row`
    per subject. Returns the rows and, per ``(title, path)``, the joint positions of the exported
    skeleton after foot locking (what the BVH holds; the network's joints for a diverged rollout)
    and the path's ideal positions (previews)."""
    upm = estimate_units_per_meter(skeleton)
    out = jax.tree.map(np.asarray, rollouts)
    floor = footlock.skeleton_floor(skeleton)  # one skeleton for the whole batch
    captures = [CaptureStyle.of(s.dataset, s.style) for s in subjects]
    rates = [capture_rate(s) for s in subjects]  # once per subject, not per path
    neutral = neutral_capture(subjects, captures)
    results, drawn = [], {}
    for k, (i, p) in enumerate(pairs):
        one = jax.tree.map(lambda v, k=k: v[k], out)
        s = subjects[i]
        e = exported(one, skeleton, floor)
        drawn[(s.title, p)] = (e.net if e.locked is None else e.locked, signals[k].positions)
        row = measure(one, skeleton, signals[k], units_per_meter=upm, out=e)
        # the steps of the locked skeleton (what is drawn) are measure's, not counted again
        fidelity = style_figures(drawn[(s.title, p)][0], skeleton, signals[k].fps, upm, captures[i], neutral,
                                 cadence=row.get("steps_per_s") if e.locked is not None else None)
        results.append({"model": s.model, "style": s.title, "kind": s.kind, "path": p, "speed_m_s": speeds[i], **row,
                        **fidelity, **phase_figures(one, signals[k], rates[i]),
                        **stepping_figures(row, signals[k], captures[i].lifted_steps_per_s)})
    for s, c in zip(subjects, captures, strict=True):
        results.append(capture_row(s, c, neutral))
    return Measured(results, drawn)


def style_figures(positions_TxJx3: np.ndarray, skeleton: Motion, fps: float, units_per_meter: float,
                  capture: CaptureStyle, neutral: CaptureStyle | None, *, cadence: float | None = None) -> dict:
    """A drawn character's style fidelity against its ``capture``
    (:func:`jaxstyle.output.style.style_distance`: ``style_distance`` and its groups, in metres),
    ``wrist_range_ratio`` (its wrists' up-and-down range over the capture's) and ``style_shows``
    (:func:`jaxstyle.output.style.shows` against the capture's distance to ``neutral``; blank for
    Neutral itself, the reference; False without a Neutral capture). ``cadence``: steps per second already counted
    on the same positions."""
    shown = style.style_stats(positions_TxJx3, skeleton, fps, units_per_meter=units_per_meter, cadence=cadence)
    fidelity = style.style_distance(shown, capture.stats)
    cap_range = capture.stats.wrist_range_m  # how much of the capture's arm movement is kept
    fidelity["wrist_range_ratio"] = shown.wrist_range_m / cap_range if cap_range > 0 else float("nan")
    fidelity["style_shows"] = (None if capture is neutral
                               else style.shows(fidelity["style_distance"], capture.to(neutral)))
    return fidelity


STALLED_MARK = "[PHASES STALLED]"
"""How :func:`jaxstyle.output.report.table` marks a path whose character's local phases stalled
(:func:`phase_figures`)."""

STALL_RATIO = 0.25
"""A character's local phases have stalled when, over the frames where its path asks it to move,
they advance at under this fraction of its style's capture rate (a quarter: a character stepping
at its capture's pace within the 25% the benchmark allows never comes near it)."""


def capture_rate(character) -> float:
    """The local phases' median advance per frame in the capture of ``character``'s style
    (anything with ``dataset`` and ``style``; :func:`jaxstyle.control.lpn_phases.capture_phase_rate`;
    0 for a dataset without local phases, whose rollouts :func:`phase_figures` leaves out)."""
    from jaxstyle.control.lpn_phases import capture_phase_rate

    phases = np.asarray(getattr(character.dataset, "phases", np.zeros((0, 0))))
    if phases.ndim != 2 or phases.shape[1:] != (8,):
        return 0.0
    return capture_phase_rate(character.dataset, character.style)


def phase_figures(rollout, signal: paths.PathSignal, capture_rate: float) -> dict:
    """For a model carrying local phases (the 2022 LPN-layout rollouts, ``phases (T, 8)``): the
    median advance of its phases per frame over the frames after the first second where the path
    asks it to move, as a fraction of its style's ``capture_rate`` (cycles per frame,
    :func:`capture_rate`), ``phase_rate_ratio``, and
    ``phases_stalled`` (below :data:`STALL_RATIO`: the closed loop froze and the character glides).
    Empty for other models."""
    from jaxstyle.control.lpn_phases import local_phase_advance

    phases = np.asarray(getattr(rollout, "phases", np.zeros((0, 0))))
    if phases.ndim != 2 or phases.shape[1] != 8 or len(phases) < 3:
        return {}
    start = int(round(signal.fps))
    moving = np.hypot(*np.asarray(signal.velocity, np.float64).T)[1:] > 1e-6
    advance = local_phase_advance(np.asarray(phases[:-1], np.float64), np.asarray(phases[1:], np.float64))
    use = moving & (np.arange(1, len(phases)) >= start)
    if not use.any() or not capture_rate > 0:
        return {"phase_rate_ratio": math.nan, "phases_stalled": None}
    ratio = float(np.median(advance[use]) / capture_rate)
    return {"phase_rate_ratio": ratio, "phases_stalled": bool(ratio < STALL_RATIO)}


NOT_STEPPING_MARK = "[NOT STEPPING]"
"""How :func:`jaxstyle.output.report.table` and ``jaxstyle synthesize``'s table mark a path whose
character hardly lifts its feet while it moves (:func:`stepping_figures`), whatever its phases do."""

STEP_RATIO = 0.5
"""A character is not stepping when, per second of the frames where its path asks it to move, it
lifts its feet (``lifted_steps_per_s`` of the drawn skeleton, :class:`jaxstyle.output.metrics.StepFigures`)
at under this fraction of its style's capture. Set halfway between a frozen pose (0) and the
benchmark's lower bound for stepping (0.75: within 25%), before the runs below and not fitted to
them; earlier paper-size runs' frozen rows had read 0.00-0.33 of their captures' lifted steps over
the whole rollout. Measured since on the paper-size protocol (``docs/mason2022.md``, "Which styles
step"): the 2018 PFNN's rows read 0.67-1.23; 2022 characters seen holding one pose or standing
while their root moved read 0.07-0.16, one seen alternating its legs with a low lift count 0.52."""


def stepping_figures(row: dict, signal: paths.PathSignal, capture_lifted: float) -> dict:
    """Of any model's row (:func:`measure`'s ``lifted_steps_per_s``, counted over the whole rollout):
    the lifted steps per second of the frames where ``signal`` asks the character to move, over
    its capture's lifted steps per second ``capture_lifted`` (:attr:`CaptureStyle.lifted_steps_per_s`),
    ``lifted_step_ratio``, and ``not_stepping`` (below :data:`STEP_RATIO`: the character glides or
    holds one pose while its root moves). It sees what :func:`phase_figures` cannot when the
    runtime floors the local phases: phases that advance under a frozen pose. NaN and ``None``
    without a figure (a diverged rollout, a path that never moves, a capture without lifted steps)."""
    lifted = float(row.get("lifted_steps_per_s", math.nan))
    speed = np.hypot(*np.asarray(signal.velocity, np.float64).T)
    moving_s = float(np.sum(speed > 1e-6)) / float(signal.fps)
    if not (np.isfinite(lifted) and moving_s > 0 and capture_lifted > 0):
        return {"lifted_step_ratio": math.nan, "not_stepping": None}
    ratio = lifted * (len(speed) / float(signal.fps)) / moving_s / float(capture_lifted)
    return {"lifted_step_ratio": ratio, "not_stepping": bool(ratio < STEP_RATIO)}


def run(model: CharacterModel, subjects: Sequence[Subject], skeleton: Motion, *,
        path_names: Sequence[str] = PROTOCOL_PATHS, seconds: float = SECONDS,
        follow_seconds: float | None = loop.FOLLOW_SECONDS) -> Measured:
    """Drive every subject of ``model`` (any :class:`jaxstyle.control.model.CharacterModel`: the
    2018 PFNN with style adapters, a 2022 style model) along every path at its style's own median
    speed (one batched rollout, :func:`jaxstyle.output.drive.drive`, with the path-following law of
    time constant ``follow_seconds``) and :func:`measure` each; then one :func:`capture_row` per
    subject. Returns the rows and, per ``(title, path)``, the exported skeleton's joint positions
    and the path's ideal positions (previews)."""
    driven = drive.drive(model, subjects, drive.Course(path_names, seconds, follow_seconds=follow_seconds),
                         units_per_meter=estimate_units_per_meter(skeleton), fps=skeleton.fps)
    return measure_rollouts(subjects, driven.pairs, driven.signals, driven.rollouts, skeleton, driven.speeds)


def capture_spec(dataset: datasets.Dataset, name: str):
    """The clip spec of a style's capture: the first clip of its start rows
    (:func:`jaxstyle.data.datasets.style_rows`: a forward walk, else a forward run, of the style;
    never a backward or sideways take while it has a forward one), as the paths move forward."""
    return dataset.specs[int(dataset.clip[style_rows(dataset, name)[0]])]


class CaptureStyle(NamedTuple):
    """A style's capture (:func:`capture_spec`) loaded once: its ``spec``, the ``clip``, its
    :class:`jaxstyle.output.style.StyleStats`, the style distance between its two halves
    (:func:`jaxstyle.output.style.halves_distance`) and its lifted steps per second
    (:func:`jaxstyle.output.metrics.step_figures`, the reference of :func:`stepping_figures`)."""

    spec: Any
    clip: Motion
    stats: style.StyleStats
    halves: float
    lifted_steps_per_s: float

    @classmethod
    def of(cls, dataset: datasets.Dataset, name: str, fps: float = 60.0) -> CaptureStyle:
        spec = capture_spec(dataset, name)
        clip = datasets.load_clip(spec, fps=fps)
        pos = global_positions(clip)
        return cls(spec, clip, style.style_stats(pos, clip, clip.fps), style.halves_distance(pos, clip, clip.fps),
                   metrics.step_figures(pos, clip, clip.fps).lifted_steps_per_s)

    def to(self, other: CaptureStyle | None) -> float:
        """The style distance from this capture to ``other``'s (NaN without one)."""
        return float("nan") if other is None else style.style_distance(self.stats, other.stats)["style_distance"]


def neutral_capture(subjects: Sequence[Subject], captures: Sequence[CaptureStyle]) -> CaptureStyle | None:
    """The capture of the subjects' Neutral style (a dataset style ``Neutral`` or ``Neutral_<GAIT>``),
    the reference a style's distance is held against; ``None`` when no subject is Neutral."""
    for s, c in zip(subjects, captures, strict=True):
        if s.style == "Neutral" or s.style.startswith("Neutral_"):
            return c
    return None


def capture_row(subject: Subject, capture: CaptureStyle | None = None, neutral: CaptureStyle | None = None) -> dict:
    """The same figures for the style's capture (forward kinematics of the BVH; no path), naming
    the file in ``capture_file``, with the style distance between its two halves
    (``style_halves_distance``) and to Neutral's capture (``style_to_neutral``)."""
    capture = capture or CaptureStyle.of(subject.dataset, subject.style)
    return {"model": subject.model, "style": subject.title, "kind": subject.kind, "path": "capture",
            "capture_file": Path(capture.spec.path).name, **capture_figures(capture.clip),
            "style_halves_distance": capture.halves, "style_to_neutral": capture.to(neutral)}
