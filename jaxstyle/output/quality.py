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
:func:`targets` checks the targets, :func:`table` and :func:`write_csv` report,
:func:`target_marks` lists chosen targets with pass/fail marks (``jaxstyle demo``), :func:`plot`
draws the bars (generated vs capture). :func:`jaxstyle.output.diagnose.diagnose` measures where
sliding and drift come from (teacher-forced vs closed loop, root vs planted-foot velocity, phase
advance vs cadence, trajectory blending, normalisation) for ``docs/quality.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
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
from jaxstyle.output import drive, footlock, style
from jaxstyle.output.drive import Character
from jaxstyle.output.measure import SLIDING_SOURCES, capture_figures, exported, measure

PROTOCOL_PATHS = ("straight", "circle", "zigzag", "stop_and_go", "speed_ramp", "waypoints")
FOLLOW_PATHS = ("straight", "circle", "zigzag")  # the paths of the 0.3 m final-error target
TARGET_PATHS = FOLLOW_PATHS + ("stop_and_go",)  # the paths of the path and stop targets (``jaxstyle demo``)
PATH_TARGETS = ("final path error <= 0.3 m", "stop within 0.5 s")  # their names in :func:`targets`
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
                        **fidelity, **phase_figures(one, signals[k], rates[i])})
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
"""How :func:`table` marks a path whose character's local phases stalled (:func:`phase_figures`)."""

STALL_RATIO = 0.25
"""A character's local phases have stalled when, over the frames where its path asks it to move,
they advance at under this fraction of its style's capture rate (a quarter: a character stepping
at its capture's pace within the 25% the benchmark allows never comes near it)."""


def capture_rate(character) -> float:
    """The local phases' median advance per frame in the capture of ``character``'s style
    (anything with ``dataset`` and ``style``; :func:`jaxstyle.control.lpn_controller.capture_phase_rate`;
    0 for a dataset without local phases, whose rollouts :func:`phase_figures` leaves out)."""
    from jaxstyle.control.lpn_controller import capture_phase_rate

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
    from jaxstyle.control.lpn_controller import local_phase_advance

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


def run(model: CharacterModel, subjects: Sequence[Subject], skeleton: Motion, *,
        path_names: Sequence[str] = PROTOCOL_PATHS, seconds: float = SECONDS,
        follow_seconds: float | None = loop.FOLLOW_SECONDS) -> Measured:
    """Drive every subject of ``model`` (any :class:`jaxstyle.control.model.CharacterModel`: the
    2018 PFNN with style adapters, a 2022 style model) along every path at its style's own median
    speed (one batched rollout, :func:`jaxstyle.output.drive.drive`, with the path-following law of
    time constant ``follow_seconds``) and :func:`measure` each; then one :func:`capture_row` per
    subject. Returns the rows and, per ``(title, path)``, the exported skeleton's joint positions
    and the path's ideal positions (previews)."""
    driven = drive.drive(model, subjects, path_names=path_names, seconds=seconds,
                         units_per_meter=estimate_units_per_meter(skeleton), fps=skeleton.fps,
                         follow_seconds=follow_seconds)
    return measure_rollouts(subjects, driven.pairs, driven.signals, driven.rollouts, skeleton, driven.speeds)


def capture_spec(dataset: datasets.Dataset, name: str):
    """The clip spec of a style's capture: the first clip of its start rows
    (:func:`jaxstyle.data.datasets.style_rows`: a forward walk, else a forward run, of the style;
    never a backward or sideways take while it has a forward one), as the paths move forward."""
    return dataset.specs[int(dataset.clip[style_rows(dataset, name)[0]])]


class CaptureStyle(NamedTuple):
    """A style's capture (:func:`capture_spec`) loaded once: its ``spec``, the ``clip``, its
    :class:`jaxstyle.output.style.StyleStats` and the style distance between its two halves
    (:func:`jaxstyle.output.style.halves_distance`)."""

    spec: Any
    clip: Motion
    stats: style.StyleStats
    halves: float

    @classmethod
    def of(cls, dataset: datasets.Dataset, name: str, fps: float = 60.0) -> CaptureStyle:
        spec = capture_spec(dataset, name)
        clip = datasets.load_clip(spec, fps=fps)
        pos = global_positions(clip)
        return cls(spec, clip, style.style_stats(pos, clip, clip.fps), style.halves_distance(pos, clip, clip.fps))

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


def _model(r: dict) -> str:
    return r.get("model") or MODEL_2018


def _capture_of(rows: list[dict]) -> dict[tuple[str, str], dict]:
    """The capture row of each ``(model, style)``."""
    return {(_model(r), r["style"]): r for r in rows if r["path"] == "capture"}


LOCK_TARGETS = ("locked skating <= capture + 0.03", "foot offset <= 0.15 m", "foot below floor <= 0.01 m",
                "steps/s within 25% of capture", "stance fraction within 0.15 of capture",
                "locked ankle jerk <= 1.5x capture")
"""The foot-locking targets :func:`targets` checks (their names), beside :data:`PATH_TARGETS`."""


STYLE_TARGET = "style distance < half capture's to Neutral"
"""The style-fidelity target (:mod:`jaxstyle.output.style`): a character's distance to its own
capture below half its capture's distance to Neutral's capture."""


def targets(rows: list[dict]) -> list[dict]:
    """One entry per (target, character, path): ``{"target", "model", "style", "path", "value",
    "limit", "met"}``. Against the style's capture: raw skating (1.5x for base styles, 2x for
    few-shot) and :data:`LOCK_TARGETS` (skating after locking at most the capture's + 0.03 m/s,
    ``steps_per_s`` within 25% and ``stance_fraction`` within 0.15 of the capture's, ankle jerk
    after locking at most 1.5x; the value of the two "within" targets is the difference from the
    capture); on every row: no foot moved more than 0.15 m by the lock, none more than 1 cm below
    the floor; final path error <= 0.3 m on straight, circle and zigzag, stop within 0.5 s, BVH bone
    error 0; and for every style but Neutral :data:`STYLE_TARGET` (the style shows)."""
    cap = _capture_of(rows)
    out = []

    def add(name, r, value, limit):
        met = bool(np.isfinite(value) and value <= limit)
        out.append({"target": name, "model": _model(r), "style": r["style"], "path": r["path"], "value": value,
                    "limit": limit, "met": met})

    nan = math.nan
    for r in rows:
        if r["path"] == "capture":
            continue
        c = cap.get((_model(r), r["style"]))
        if c is not None:
            factor = 1.5 if r["kind"] == "base" else 2.0
            add(f"raw skating <= {factor:g}x capture", r, r["foot_skating_m_s"], factor * c["foot_skating_m_s"])
            add(LOCK_TARGETS[0], r, r["foot_skating_locked_m_s"], c["foot_skating_m_s"] + 0.03)
            steps, ref = r.get("steps_per_s", nan), c.get("steps_per_s", nan)
            add(LOCK_TARGETS[3], r, abs(steps - ref) / ref if ref > 0 else nan, 0.25)
            add(LOCK_TARGETS[4], r, abs(r.get("stance_fraction", nan) - c.get("stance_fraction", nan)), 0.15)
            add(LOCK_TARGETS[5], r, r["ankle_jerk_locked_m_s3"], 1.5 * c["ankle_jerk_m_s3"])
            to_neutral = c.get("style_to_neutral", nan)
            if to_neutral is not None and np.isfinite(to_neutral) and to_neutral > 0:  # not Neutral itself
                add(STYLE_TARGET, r, r.get("style_distance", nan), 0.5 * to_neutral)
        add(LOCK_TARGETS[1], r, r.get("ik_foot_offset_max_m", nan), 0.15)
        add(LOCK_TARGETS[2], r, r.get("foot_below_floor_m", nan), 0.01)
        if r["path"] in FOLLOW_PATHS:
            add("final path error <= 0.3 m", r, r["path_error_final_m"], 0.3)
        if r["path"] == "stop_and_go" and r.get("stop_commands", 1) != 0:  # 0: a path too short to stop on
            add("stop within 0.5 s", r, r["stop_time_s"], 0.5)
        add("BVH bone error 0", r, r.get("bone_error_bvh_max", float("nan")), 1e-6)
    return out


def target_summary(checks: list[dict]) -> list[str]:
    """Markdown lines: per model and target, how many (character, path) pairs meet it, and the worst value."""
    lines = ["| model | target | met | worst value (style, path) |", "|---|---|---|---|"]
    for model, name in dict.fromkeys((c.get("model", MODEL_2018), c["target"]) for c in checks):
        mine = [c for c in checks if c["target"] == name and c.get("model", MODEL_2018) == model]
        met = sum(c["met"] for c in mine)
        worst = max(mine, key=lambda c: (c["value"] - c["limit"]) if np.isfinite(c["value"]) else math.inf)
        lines.append(f"| {model} | {name} | {met} / {len(mine)} | {_f(worst['value'], 3)} vs "
                     f"{_f(worst['limit'], 3)} ({worst['style']}, {worst['path']}) |")
    return lines


def target_marks(checks: list[dict], names: Sequence[str] = PATH_TARGETS) -> list[str]:
    """Markdown lines: every check of the targets ``names`` (default the path and stop targets)
    with its value, its limit and a pass/FAIL mark, then one line counting them (and each target's
    count when there are several)."""
    mine = [c for c in checks if c["target"] in names]
    lines = ["| model | style | path | target | value | limit | |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {c.get('model', MODEL_2018)} | {c['style']} | {c['path']} | {c['target']} | {_f(c['value'], 2)} | "
              f"{_f(c['limit'], 2)} | {'pass' if c['met'] else 'FAIL'} |" for c in mine]
    met = sum(c["met"] for c in mine)
    blank = sum(not np.isfinite(c["value"]) for c in mine)
    note = f" ({blank} n/a: never stopped before the path moved on or ended, or a diverged rollout)" if blank else ""
    each = [f"{n} {sum(c['met'] for c in mine if c['target'] == n)}/{sum(c['target'] == n for c in mine)}"
            for n in names if any(c["target"] == n for c in mine)]
    detail = f" ({'; '.join(each)})" if len(each) > 1 else ""
    return lines + ["", f"{', '.join(names)}: {met} of {len(mine)} met{note}{detail}"]


def _f(v, digits: int = 2) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def table(rows: list[dict]) -> list[str]:
    """The benchmark's markdown table: per model (in order of appearance) and style, its capture
    row (naming the capture's file), then one row per path."""
    head = ("| model | style | path | skating m/s net / BVH / locked | steps/s locked (BVH) | stance | "
            "slide/contact m | foot offset m | below floor m | bone error net max / BVH | "
            "path error mean / final m (final %) | heading deg | stop s | jitter m/s^3 | "
            "ankle jerk net / locked m/s^3 | style distance m (shows) / capture: halves, to Neutral |")
    lines = [head, "|" + "---|" * 16]
    order = {m: i for i, m in enumerate(dict.fromkeys(_model(r) for r in rows))}
    for r in sorted(rows, key=lambda r: (order[_model(r)], r["style"], r["path"] != "capture")):
        g = r.get
        path = f"capture ({r['capture_file']})" if r["path"] == "capture" and g("capture_file") else r["path"]
        path += stalled_mark(r)  # the closed loop froze: said, not hidden
        lines.append(
            f"| {_model(r)} | {r['style']} | {path} | {_f(r['foot_skating_m_s'])} / "
            f"{_f(r['foot_skating_bvh_m_s'])} / {_f(g('foot_skating_locked_m_s'))} | "
            f"{_f(g('steps_per_s'))} ({_f(g('steps_per_s_bvh'))}) | {_f(g('stance_fraction'))} | "
            f"{_f(g('slide_per_contact_m'), 3)} | {_f(g('ik_foot_offset_max_m'), 3)} | "
            f"{_f(g('foot_below_floor_m'), 3)} | "
            f"{100 * g('bone_error_max', math.nan):.1f}% / {100 * g('bone_error_bvh_max', math.nan):.1g}%"
            f" | {_f(g('path_error_mean_m'))} / "
            f"{_f(g('path_error_final_m'))} ({_f(g('path_error_final_pct'), 1)}%) | "
            f"{_f(g('heading_error_deg'), 1)} | {_f(g('stop_time_s'))} | {_f(g('jitter_m_s3'), 0)} | "
            f"{_f(g('ankle_jerk_m_s3'), 0)} / {_f(g('ankle_jerk_locked_m_s3'), 0)} | {_style_cell(r)} |")
    return lines


def _style_cell(r: dict) -> str:
    """The style-distance cell of :func:`table`: a character's distance to its capture and whether its
    style shows; a capture's distance between its halves and to Neutral's capture."""
    g = r.get
    if r["path"] == "capture":
        return f"{_f(g('style_halves_distance', math.nan))}, {_f(g('style_to_neutral', math.nan))}"
    return f"{_f(g('style_distance', math.nan))}{shows_mark(r)}"


def stalled_mark(r: dict) -> str:
    """`` [PHASES STALLED]`` (:data:`STALLED_MARK`) for a row (or a CSV row) whose local phases
    stalled (:func:`phase_figures`), else nothing."""
    return f" {STALLED_MARK}" if r.get("phases_stalled") in (True, "True") else ""


def shows_mark(r: dict) -> str:
    """`` (shows)`` or `` (no)`` for a row (or a CSV row) whose ``style_shows`` is set
    (:func:`style_figures`), else nothing (Neutral, the reference, and the captures' rows)."""
    shows = r.get("style_shows")
    return "" if shows is None or shows == "" else (" (shows)" if shows in (True, "True") else " (no)")


def write_csv(rows: list[dict], path: str | os.PathLike) -> Path:
    """The rows as CSV (the union of their keys as columns)."""
    path = Path(path)
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, restval="")
        w.writeheader()
        w.writerows(rows)
    return path


PLOTTED = (("foot_skating_m_s", "skating, network joints (m/s)"),
           ("foot_skating_locked_m_s", "skating after foot locking (m/s)"), ("steps_per_s", "steps/s after locking"),
           ("stance_fraction", "stance fraction"), ("jitter_m_s3", "jitter (m/s^3)"),
           ("ankle_jerk_locked_m_s3", "ankle jerk after locking (m/s^3)"))


def plot(rows: list[dict], path: str | os.PathLike) -> Path:
    """Bars per metric: each (model, style)'s generated motion (mean over the paths) beside its capture."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cap = _capture_of(rows)
    styles = list(cap)
    several = len({m for m, _ in styles}) > 1
    if several:  # one metric per row, wide enough for every (model, style)
        fig, axes = plt.subplots(len(PLOTTED), 1, figsize=(max(6.0, 0.32 * len(styles)), 2.6 * len(PLOTTED)))
    else:
        fig, axes = plt.subplots(1, len(PLOTTED), figsize=(3.2 * len(PLOTTED), 3.4))
    x = np.arange(len(styles))
    for ax, (key, label) in zip(axes, PLOTTED, strict=True):
        gen = [np.nanmean([r[key] for r in rows if (_model(r), r["style"]) == s and r["path"] != "capture"])
               for s in styles]
        ax.bar(x - 0.2, gen, 0.4, label="generated")
        ax.bar(x + 0.2, [cap[s][key] for s in styles], 0.4, label="capture")
        ax.set_xticks(x, [s.split(" ")[0] + (f" ({m})" if several else "") for m, s in styles], rotation=30,
                      ha="right", fontsize=8)
        ax.set_title(label, fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


# --- diagnosis -----------------------------------------------------------------------------------------------------

def lock_comparison(rows: list[dict]) -> list[str]:
    """Markdown lines comparing, on the same rollouts, the plain contact IK (:func:`pinned_feet`)
    with foot locking: per model, how many (character, path) rows meet each foot target after
    each, the medians, and where the skating left after locking comes from (median shares of
    :func:`sliding_sources`)."""
    cap = _capture_of(rows)
    lines = ["| model | post-process | skating <= capture + 0.03 | steps/s within 25% | foot offset <= 0.15 m | "
             "ankle jerk <= 1.5x capture | median skating m/s | median foot offset m | median ankle jerk m/s^3 |",
             "|---|---|---|---|---|---|---|---|---|"]
    for model in dict.fromkeys(_model(r) for r in rows):
        mine = [r for r in rows if _model(r) == model and r["path"] != "capture" and r.get("finite", True)
                and (model, r["style"]) in cap]
        if not mine:
            continue
        for name, skate, steps, offset, jerk in (
                ("none (BVH)", "foot_skating_bvh_m_s", "steps_per_s_bvh", None, "ankle_jerk_bvh_m_s3"),
                ("feet raised to the floor only", "foot_skating_floor_m_s", None, None, None),
                ("contact IK (pinned)", "foot_skating_pinned_m_s", "steps_per_s_pinned", "ik_foot_offset_max_pinned_m",
                 "ankle_jerk_pinned_m_s3"),
                ("foot locking", "foot_skating_locked_m_s", "steps_per_s", "ik_foot_offset_max_m",
                 "ankle_jerk_locked_m_s3")):
            c = [cap[(model, r["style"])] for r in mine]
            n = len(mine)

            def met(key, ok, mine=mine, c=c, n=n):
                if key is None:
                    return ""
                return f"{sum(ok(r.get(key, math.nan), k) for r, k in zip(mine, c, strict=True))} / {n}"

            def med(key, digits, mine=mine):
                return "" if key is None else _f(float(np.nanmedian([r.get(key, math.nan) for r in mine])), digits)

            cells = [met(skate, lambda v, k: v <= k["foot_skating_m_s"] + 0.03),
                     met(steps, lambda v, k: abs(v - k["steps_per_s"]) <= 0.25 * k["steps_per_s"]),
                     met(offset, lambda v, k: v <= 0.15), met(jerk, lambda v, k: v <= 1.5 * k["ankle_jerk_m_s3"]),
                     med(skate, 3), med(offset, 3), med(jerk, 0)]
            lines.append(f"| {model} | {name} | " + " | ".join(cells) + " |")
    lines += ["", "Where the skating left after locking comes from (median share of the travel of heels and toes "
              "within 1 cm of the floor, :func:`jaxstyle.output.measure.sliding_sources`):", "",
              "| model | " + " | ".join(SLIDING_SOURCES) + " |", "|---|" + "---|" * len(SLIDING_SOURCES)]
    for model in dict.fromkeys(_model(r) for r in rows):
        mine = [r for r in rows if _model(r) == model and r["path"] != "capture" and "sliding_held" in r]
        if mine:
            shares = [_f(float(np.nanmedian([r[f"sliding_{k.replace(', ', '_')}"] for r in mine])))
                      for k in SLIDING_SOURCES]
            lines.append(f"| {model} | " + " | ".join(shares) + " |")
    return lines
