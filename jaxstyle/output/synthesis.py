"""Drive styled characters along user paths and write what they did: GIF, BVH, quality figures.

The runtime of both papers (Mason et al. 2018 section 7.1, the PFNN with a style's residual
adapter in the loop; Mason, Starke & Komura 2022 section 4.4, a style model with a FiLM vector, a
one-hot row or an adapter) for several (style, path) characters of any
:class:`jaxstyle.control.model.CharacterModel` at once: every character is generated in ONE
batched, jitted ``lax.scan`` (:func:`jaxstyle.output.drive.drive`, the weights broadcast), each
starting from a real pose of its own style chosen to match the requested speed. Then, per path, a
GIF of the exported skeletons side by side (:mod:`jaxstyle.output.preview`), per (style, path) a BVH
(feet locked while planted, :mod:`jaxstyle.output.footlock`, unless ``foot_lock=False``) and an
``.npz`` (:mod:`jaxstyle.output.export`), and a table of :mod:`jaxstyle.output.metrics` figures beside
those of real motion of each style: of the network's own joints, and of the exported skeleton (the
BVH's, before and after foot locking) by the quality benchmark's
:func:`jaxstyle.output.measure.measure`, so what a user sees in Blender is measured.

Used by ``jaxstyle synthesize`` / ``jaxstyle demo`` (:mod:`jaxstyle.cli`).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Sequence

import jax
import numpy as np

from jaxstyle.control.model import CharacterModel
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.output import drive, export, footlock, measure, metrics, preview, quality, report
from jaxstyle.output.drive import Character
from jaxstyle.output.report import figure as _f


@dataclasses.dataclass
class SynthesisResult:
    """``rows``: one :class:`jaxstyle.output.metrics.MotionQuality` row per (character, path) and per real
    clip; ``files``: everything written; ``seconds``: rollout time (compiled) and ``frames``;
    ``speeds``: each character's walking speed (m/s) by title."""

    rows: list[dict]
    files: list[Path]
    seconds: float
    frames: int
    speeds: dict[str, float]

    def summary(self, num_characters: int, num_paths: int) -> str:
        """One line: characters x paths, frames and speed of the batched rollout."""
        return (f"{num_characters} characters x {num_paths} paths, {self.frames:,} frames in one batched rollout: "
                f"{self.seconds:.2f} s ({self.frames / max(self.seconds, 1e-9):,.0f} frames/s)")


@dataclasses.dataclass(frozen=True)
class SynthesisOptions:
    """What a synthesis drives and writes.

    ``path_names``: any of :data:`jaxstyle.control.paths.PATHS`, ``seconds`` long each; ``speed``:
    m/s for every character (``None``: each walks at its style's own median speed);
    ``foot_lock``: lock the feet while planted (:mod:`jaxstyle.output.footlock`) in the BVH files
    and the animations (drawn from the exported skeleton); ``gif``/``mp4``: write animations
    (``mp4`` needs ffmpeg), drawing every ``every``-th frame; ``contact_sheet``: a PNG strip of 6
    frames of the first path; ``reference``: add the quality figures of one real clip per style to
    the table; ``progress``: progress bars while drawing."""

    path_names: tuple[str, ...] = ("circle",)
    seconds: float = 8.0
    speed: float | None = None
    foot_lock: bool = True
    gif: bool = True
    mp4: bool = False
    every: int = 2
    contact_sheet: bool = False
    reference: bool = True
    progress: bool = False

    def __post_init__(self):
        object.__setattr__(self, "path_names", tuple(self.path_names))


def synthesize(model: CharacterModel, characters: Sequence[Character], skeleton: Motion, out: str | os.PathLike,
               options: SynthesisOptions = SynthesisOptions()) -> SynthesisResult:
    """Drive every character along every path of ``options`` (:class:`SynthesisOptions`) in one
    batched rollout and write the results under ``out``.

    ``model``: any :class:`jaxstyle.control.model.CharacterModel` (the 2018
    :class:`jaxstyle.control.controller.PFNNModel`, a 2022
    :class:`jaxstyle.control.lpn_controller.StyleNetModel`); ``characters``: the styles
    (:class:`jaxstyle.output.drive.Character`, their conditionings of one kind for the model);
    ``skeleton``: a clip of the training skeleton (bone lengths, fps, units).

    Writes ``<path>.gif`` per path, ``bvh/<label>_<path>.bvh`` and ``.npz`` per character and
    path, ``contact_sheet.png`` if asked, and ``quality.csv`` (:func:`write_results`).
    """
    o = options
    driven = drive.drive(model, characters, drive.Course(o.path_names, o.seconds, o.speed),
                         units_per_meter=estimate_units_per_meter(skeleton), fps=skeleton.fps, timed=True)
    rows, files = write_results(out, characters, driven, skeleton, options)
    return SynthesisResult(rows, files, driven.seconds, len(driven.pairs) * int(driven.rollouts.positions.shape[1]),
                           dict(zip([c.title for c in characters], driven.speeds, strict=True)))


def write_results(out: str | os.PathLike, characters: Sequence, driven: drive.Driven, skeleton: Motion,
                  options: SynthesisOptions = SynthesisOptions()) -> tuple[list[dict], list[Path]]:
    """What a synthesis writes, from a batched rollout of any model (:class:`jaxstyle.output.drive.Driven`:
    its :class:`jaxstyle.control.model.Frames` with leading axis ``len(pairs)``, the pairs and path
    signals): per path a GIF (and MP4, contact sheet) of the exported skeleton (after foot locking
    with ``options.foot_lock``: what the BVH files hold), per (character, path) the
    :mod:`jaxstyle.output.metrics` row, the BVH and ``.npz``, the real clips' rows, ``quality.csv``.

    ``characters``: anything with ``title``, ``label``, ``dataset`` and ``style``
    (:class:`jaxstyle.output.drive.Character`). The
    metrics read the skeleton's joints (the LPN's extra hand points are left out), with the same
    functions for both models: :func:`jaxstyle.output.metrics.motion_quality` of the network's joints
    (the row's first columns, path error of the root joint's ground point) and the benchmark's
    figures of the exported skeleton (:func:`jaxstyle.output.measure.measure`, :data:`EXPORTED_FIGURES`:
    skating of the BVH before and after foot locking, stepping after it, how far the lock moved a
    foot, how deep a foot goes below the floor, its bone error, the largest network-to-BVH joint
    distance, heading error, time to stop, ankle jerk). Returns the quality rows and the files written."""
    out = Path(out)
    pairs, signals, rollouts = driven.pairs, driven.signals, driven.rollouts
    foot_lock, every, progress = options.foot_lock, options.every, options.progress
    upm = estimate_units_per_meter(skeleton)
    fps = skeleton.fps
    path_names = list(dict.fromkeys(p for _, p in pairs))
    joints = skeleton.num_joints
    out.mkdir(parents=True, exist_ok=True)
    files, rows = [], []
    titles = [c.title for c in characters]
    ones = [jax.tree.map(lambda v, k=k: np.asarray(v[k]), rollouts) for k in range(len(pairs))]
    floor = footlock.skeleton_floor(skeleton)  # one skeleton for every rollout
    shown = [measure.exported(one, skeleton, floor) for one in ones]

    def drawn(e):
        return e.net if e.bvh is None else (e.locked if foot_lock else e.bvh)

    for p in path_names:
        idx = [k for k, (_, q) in enumerate(pairs) if q == p]
        chars = [drawn(shown[k]) for k in idx]
        path_xz = [signals[k].positions for k in idx]
        drawing = preview.Drawing(titles=titles, paths=path_xz, units_per_meter=upm)
        if options.gif:
            files.append(preview.render_gif(out / f"{p}.gif", chars, skeleton.parents, fps, drawing, every=every,
                                            progress=progress))
        if options.mp4:
            files.append(preview.render_mp4(out / f"{p}.mp4", chars, skeleton.parents, fps, drawing, every=every,
                                            progress=progress))
        if options.contact_sheet and p == path_names[0]:
            files.append(preview.contact_sheet(out / "contact_sheet.png", chars, skeleton.parents, drawing, frames=6,
                                               fps=fps))
    # each character's capture (and its phase rate), once per (dataset, style), and Neutral's: the
    # style distance's references; the real clips' rows below read the same clips
    captures = {}
    for c in characters:
        if (id(c.dataset), c.style) not in captures:
            captures[(id(c.dataset), c.style)] = (quality.CaptureStyle.of(c.dataset, c.style, fps),
                                                  quality.capture_rate(c))
    of = [captures[(id(c.dataset), c.style)][0] for c in characters]
    rates = [captures[(id(c.dataset), c.style)][1] for c in characters]
    neutral = quality.neutral_capture(characters, of)
    for k, (s, p) in enumerate(pairs):
        one, e = ones[k], shown[k]
        c = characters[s]
        q = metrics.motion_quality(np.asarray(one.positions)[:, :joints], skeleton, fps, units_per_meter=upm,
                                   path_Tx2=signals[k].positions)
        row = {"style": c.title, "path": p, "foot_lock": bool(foot_lock), **q.as_row()}
        measured = measure.measure(one, skeleton, signals[k], units_per_meter=upm, out=e)
        row.update({key: measured.get(key, float("nan")) for key in EXPORTED_FIGURES})
        row.update(quality.phase_figures(one, signals[k], rates[s]))  # a 2022 character whose phases stalled
        row.update(quality.stepping_figures(row, signals[k], of[s].lifted_steps_per_s))  # or whose feet froze
        row.update(quality.style_figures(drawn(e), skeleton, fps, upm, of[s], neutral,
                                         cadence=row.get("steps_per_s") if e.locked is not None and foot_lock
                                         else None))
        if e.lock is not None:
            motion = e.lock.motion if foot_lock else export.rollout_motion(one, skeleton)
            files += export.save_rollout(out / "bvh" / f"{c.label}_{p}", one, skeleton, motion=motion).values()
        rows.append(row)
    if options.reference:
        seen = set()
        for c, capture in zip(characters, of, strict=True):
            if id(capture) in seen:
                continue
            seen.add(id(capture))
            q = metrics.reference_quality(capture.clip, units_per_meter=upm)
            real = measure.capture_figures(capture.clip)
            rows.append({"style": c.title, "path": f"real ({Path(capture.spec.path).name})", **q.as_row(),
                         **{key: real[key] for key in EXPORTED_FIGURES}})
    files.append(report.write_csv(rows, out / "quality.csv"))
    return rows, files


EXPORTED_FIGURES = ("foot_skating_bvh_m_s", "foot_skating_locked_m_s", *measure.LOCK_FIGURES, "bone_error_bvh_max",
                    "joint_difference_max_m", "heading_error_deg", "stop_time_s", "ankle_jerk_m_s3",
                    "ankle_jerk_locked_m_s3")
"""The columns :func:`write_results` adds from :func:`jaxstyle.output.measure.measure` (its
stepping and foot-lock columns are :data:`jaxstyle.output.measure.LOCK_FIGURES`); the real
clips' rows have the figures of their own skeleton there."""


def quality_table(rows: list[dict]) -> list[str]:
    """Markdown lines of the main quality figures: skating of the network's own joints, of the
    exported BVH's skeleton and of that skeleton after foot locking (what the BVH files hold by
    default), steps per second (contact onsets, then lifted steps) and stance fraction after
    locking, how far the lock moved a foot, bone error of the network's joints and of the BVH, path
    error, time to stop, jitter, and the style distance to the character's capture with whether the
    style shows (:func:`jaxstyle.output.quality.style_figures`, on what is drawn; :func:`write_results`).
    A 2022 character whose local phases stalled has its path marked
    :data:`jaxstyle.output.quality.STALLED_MARK` (:func:`jaxstyle.output.quality.phase_figures`), a
    character of any model that hardly lifts its feet while it moves
    :data:`jaxstyle.output.quality.NOT_STEPPING_MARK` (:func:`jaxstyle.output.quality.stepping_figures`)."""
    lines = ["| style | path | skating m/s network / BVH / locked | steps/s, lifted | stance | foot offset m "
             "| bone error network mean / max / BVH max | path error mean / final m | stop s | jitter m/s^3 "
             "| style distance m (shows) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        g = r.get
        path = r["path"] + report.stalled_mark(r)
        lines.append(f"| {r['style']} | {path} | {_f(g('foot_skating_m_s'))} / {_f(g('foot_skating_bvh_m_s'))} / "
                     f"{_f(g('foot_skating_locked_m_s'))} | {_f(g('steps_per_s'))}, {_f(g('lifted_steps_per_s'))} "
                     f"| {_f(g('stance_fraction'))} "
                     f"| {_f(g('ik_foot_offset_max_m'), 3)} "
                     f"| {_f(100 * r['bone_error_mean'], 1)}% / {_f(100 * r['bone_error_max'], 0)}% / "
                     f"{_f(100 * float(g('bone_error_bvh_max', 'nan')), 0)}% "
                     f"| {_f(g('path_error_mean_m'))} / {_f(g('path_error_final_m'))} | {_f(g('stop_time_s'))} "
                     f"| {_f(g('jitter_m_s3'), 0)} | {_style(r)} |")
    return lines


def _style(r: dict) -> str:
    """The style distance cell: the distance to the capture and whether the style shows (blank
    for a real clip's row and for Neutral, the reference)."""
    d = r.get("style_distance")
    if d is None or d == "":
        return ""
    return f"{_f(d)}{report.shows_mark(r)}"
