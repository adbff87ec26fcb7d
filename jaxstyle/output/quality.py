"""The motion-quality benchmark of ``experiments/quality.py``: every character along the
six protocol paths, measured as the user sees it, beside the same figures of its style's capture.

Per (character, path), from ONE batched closed-loop rollout with the path-following law of
:mod:`jaxstyle.control.loop` (:func:`run`, for any :class:`jaxstyle.control.model.CharacterModel`:
the 2018 PFNN with style adapters, the 2022 style models; measured by the one function
:func:`measure`):

* foot skating (:func:`jaxstyle.output.metrics.foot_skating`) of the network's own joints, of the
  exported skeleton (the BVH's forward kinematics: bone lengths exact, :mod:`jaxstyle.output.export`)
  and of the exported skeleton after foot locking (:func:`jaxstyle.output.export.lock_feet`, what
  the BVH holds: contacts from the motion, started also by the network's predicted labels);
* stepping after locking (steps per second, stance fraction, slide per contact:
  :func:`jaxstyle.output.metrics.step_figures`), the largest distance the lock moved a foot and
  how deep a foot goes below the floor (:data:`LOCK_FIGURES`);
* feet on the floor, bone error of the network's joints and of the BVH (0 by construction), and
  the largest distance between the network's joints and the BVH's;
* path error (mean, final, final as % of the path's length), heading error, the time to stop
  after each stop command (:func:`jaxstyle.output.metrics.stop_times`), jitter and ankle jerk.

:func:`capture_row` gives the same figures for a forward clip of the style's capture
(:func:`capture_clip`; no path: those are blank). Every row names its ``model``
(:data:`MODEL_2018` or the 2022 model's Table 2 name).
:func:`targets` checks the targets, :func:`table` and :func:`write_csv` report,
:func:`target_marks` lists chosen targets with pass/fail marks (``jaxstyle demo``), :func:`plot`
draws the bars (generated vs capture). :func:`diagnose` measures where sliding and
drift come from (teacher-forced vs closed loop, root vs planted-foot velocity, phase advance vs
cadence, trajectory blending, normalisation) for ``docs/quality.md``.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop, paths
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.model import CharacterModel, Frames, rollout
from jaxstyle.data import datasets
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.labels.contacts import FootJoints, body_units_per_meter, estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.motion.kinematics import global_positions
from jaxstyle.nn import pfnn
from jaxstyle.output import drive, export, footlock, metrics
from jaxstyle.output.drive import Character

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


def measure_rollouts(subjects: Sequence[Subject], pairs: Sequence[tuple[int, str]], signals: Sequence[paths.PathSignal],
                     rollouts, skeleton: Motion, speeds: Sequence[float]
                     ) -> tuple[list[dict], Drawn]:
    """:func:`measure` each rollout of a batch of any model (leading axis ``len(pairs)``,
    ``pairs[k] = (subject index, path name)`` along ``signals[k]``), then one :func:`capture_row`
    per subject. Returns the rows and, per ``(title, path)``, the joint positions of the exported
    skeleton after foot locking (what the BVH holds; the network's joints for a diverged rollout)
    and the path's ideal positions (previews)."""
    upm = estimate_units_per_meter(skeleton)
    out = jax.tree.map(np.asarray, rollouts)
    floor = footlock.skeleton_floor(skeleton)  # one skeleton for the whole batch
    results, drawn = [], {}
    for k, (i, p) in enumerate(pairs):
        one = jax.tree.map(lambda v, k=k: v[k], out)
        s = subjects[i]
        e = exported(one, skeleton, floor)
        drawn[(s.title, p)] = (e.net if e.locked is None else e.locked, signals[k].positions)
        row = measure(one, skeleton, signals[k], units_per_meter=upm, out=e)
        results.append({"model": s.model, "style": s.title, "kind": s.kind, "path": p, "speed_m_s": speeds[i], **row})
    for s in subjects:
        results.append(capture_row(s))
    return results, drawn


def run(model: CharacterModel, subjects: Sequence[Subject], skeleton: Motion, *,
        path_names: Sequence[str] = PROTOCOL_PATHS, seconds: float = SECONDS,
        follow_seconds: float | None = loop.FOLLOW_SECONDS) -> tuple[list[dict], Drawn]:
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


class Exported(NamedTuple):
    """A rollout as the user gets it: the network's joints ``net``, the exported skeleton's joints
    before (``bvh``) and after foot locking (``locked``, what the BVH file holds), the lock's
    :class:`jaxstyle.output.footlock.LockedMotion` (``None`` when the outputs are not finite), and
    for comparison ``pinned``: the skeleton after the plain contact IK of the 2022 paper's section
    4.4 (:func:`pinned_feet`); ``floor_2x2``, the training skeleton's planted heights the lock and
    the floor figures use."""

    net: np.ndarray
    bvh: np.ndarray | None
    locked: np.ndarray | None
    lock: Any
    pinned: np.ndarray | None
    floor_2x2: np.ndarray


def raised_to_floor(positions_TxJx3: np.ndarray, skeleton: Motion, floor_2x2: np.ndarray) -> np.ndarray:
    """The positions with every heel and toe below its planted height ``floor_2x2`` (``[side,
    heel/toe]``, e.g. :func:`jaxstyle.output.footlock.skeleton_floor` of the training skeleton)
    raised onto it, nothing else changed: what the floor alone does to the skating figure (feet
    that glide through the floor glide on it)."""
    out = np.array(positions_TxJx3, dtype=np.float64, copy=True)
    feet, floor = FootJoints.find(skeleton), np.asarray(floor_2x2, dtype=np.float64)
    for side in range(2):
        for k, j in enumerate((feet.ankles[side], feet.toes[side])):
            out[:, j, 1] = np.maximum(out[:, j, 1], floor[side, k])
    return out


def pinned_feet(motion: Motion, rollout) -> Motion:
    """The baseline post-process: heels and toes pinned while the network's predicted contact
    labels are on (:func:`jaxstyle.output.footik.fix_foot_sliding`, 5 blend frames), or, for a model
    without contact outputs, while within 1 cm of the floor for at least 0.1 s; no speed test,
    no reach limit."""
    from jaxstyle.labels.contacts import foot_contacts
    from jaxstyle.output import footik

    contacts = export.network_contacts(rollout, motion.num_joints)
    if contacts is None:
        c = foot_contacts(motion, speed_threshold=None, min_duration=0.1)
        contacts = np.concatenate([c.heel, c.toe], axis=1)
    return footik.fix_foot_sliding(motion, contacts, blend_frames=5, pin_toes=True)


def exported(rollout: Frames, skeleton: Motion,
             floor_2x2: np.ndarray | None = None) -> Exported:
    """:class:`Exported` of one character's rollout of any model (the network's joints are the
    skeleton's: an LPN rollout's extra hand points are left out). ``floor_2x2``: the skeleton's
    planted heights (:func:`jaxstyle.output.footlock.skeleton_floor`, computed when omitted; pass
    it to measure many rollouts on one skeleton)."""
    floor = footlock.skeleton_floor(skeleton) if floor_2x2 is None else np.asarray(floor_2x2)
    net = np.asarray(rollout.positions, dtype=np.float64)[:, :skeleton.num_joints]
    if not np.isfinite(np.asarray(rollout.outputs)).all():
        return Exported(net, None, None, None, None, floor)
    motion = export.rollout_motion(rollout, skeleton)
    lock = export.lock_feet(motion, rollout, floor_2x2=floor)
    return Exported(net, global_positions(motion), global_positions(lock.motion), lock,
                    global_positions(pinned_feet(motion, rollout)), floor)


LOCK_FIGURES = ("steps_per_s", "stance_fraction", "slide_per_contact_m", "steps_per_s_bvh", "ik_foot_offset_max_m",
                "foot_below_floor_m")
"""The stepping and foot-lock columns of :func:`measure` (``steps_per_s``, ``stance_fraction`` and
``slide_per_contact_m`` of the locked skeleton, :func:`jaxstyle.output.metrics.step_figures`;
``steps_per_s_bvh`` before locking)."""


def measure(rollout: Frames, skeleton: Motion, signal: paths.PathSignal, *,
            units_per_meter: float, out: Exported | None = None) -> dict:
    """The figures of one character's rollout along ``signal`` (see the module docstring), of any
    model: the network's joints, the exported skeleton (the BVH's,
    :func:`jaxstyle.output.export.rollout_motion` decodes both models' outputs) and the same after
    foot locking (:func:`jaxstyle.output.export.lock_feet`, the network's own contacts starting
    locks when it predicts them): skating of all three, stepping of the locked skeleton
    (:data:`LOCK_FIGURES`), how far the lock moved a foot and how deep a foot goes below the
    training skeleton's floor; and for comparison the same of the plain contact IK
    (:func:`pinned_feet`, ``*_pinned`` columns). ``out``: :func:`exported` of the rollout, if already
    computed."""
    upm, fps = float(units_per_meter), float(signal.fps)
    e = exported(rollout, skeleton) if out is None else out
    net = e.net
    nan = float("nan")
    row = {"foot_skating_m_s": nan, "foot_skating_bvh_m_s": nan, "foot_skating_locked_m_s": nan}
    if e.bvh is None:
        return {**row, "finite": False}
    bvh, after = e.bvh, e.locked
    bones = metrics.bone_length_errors(net, skeleton)
    err = np.linalg.norm(np.asarray(rollout.origin) - signal.positions, axis=-1) / upm
    length = float(np.sum(np.linalg.norm(signal.velocity, axis=1)) / fps / upm)
    stops = metrics.stop_times(rollout.origin, signal.velocity, fps, units_per_meter=upm)
    q = metrics.motion_quality(net, skeleton, fps, units_per_meter=upm)
    steps = metrics.step_figures(after, skeleton, fps)
    return {
        "finite": True,
        "foot_skating_m_s": metrics.foot_skating(net, skeleton, fps, units_per_meter=upm),
        "foot_skating_bvh_m_s": metrics.foot_skating(bvh, skeleton, fps, units_per_meter=upm),
        "foot_skating_locked_m_s": metrics.foot_skating(after, skeleton, fps, units_per_meter=upm),
        "contact_fraction": q.contact_fraction,
        **dataclasses.asdict(steps),
        "steps_per_s_bvh": metrics.step_figures(bvh, skeleton, fps).steps_per_s,
        "ik_foot_offset_max_m": metrics.foot_offset_max_m(bvh, after, skeleton, units_per_meter=upm),
        "foot_below_floor_m": metrics.foot_below_floor_m(after, skeleton, e.floor_2x2,
                                                         units_per_meter=upm),
        "bone_error_mean": float(np.mean(bones)), "bone_error_max": float(np.max(bones)),
        "bone_error_bvh_max": float(np.max(metrics.bone_length_errors(bvh, skeleton))),
        "joint_difference_max_m": metrics.max_joint_difference_m(net, bvh, units_per_meter=upm),
        "path_error_mean_m": float(np.mean(err)), "path_error_final_m": float(err[-1]),
        "path_error_final_pct": 100.0 * float(err[-1]) / length if length > 0 else nan,
        "heading_error_deg": metrics.heading_error_deg(rollout.yaw, signal.yaw),
        "stop_time_s": float(np.max(stops)) if len(stops) else nan, "stop_commands": int(len(stops)),
        "jitter_m_s3": q.jitter_m_s3,
        "ankle_jerk_m_s3": metrics.foot_jerk(net, skeleton, fps, units_per_meter=upm),
        "foot_skating_floor_m_s": metrics.foot_skating(raised_to_floor(bvh, skeleton, e.floor_2x2), skeleton, fps,
                                                       units_per_meter=upm),
        "ankle_jerk_bvh_m_s3": metrics.foot_jerk(bvh, skeleton, fps, units_per_meter=upm),
        "ankle_jerk_locked_m_s3": metrics.foot_jerk(after, skeleton, fps, units_per_meter=upm),
        **({} if e.pinned is None else {
            "foot_skating_pinned_m_s": metrics.foot_skating(e.pinned, skeleton, fps, units_per_meter=upm),
            "steps_per_s_pinned": metrics.step_figures(e.pinned, skeleton, fps).steps_per_s,
            "ik_foot_offset_max_pinned_m": metrics.foot_offset_max_m(bvh, e.pinned, skeleton, units_per_meter=upm),
            "ankle_jerk_pinned_m_s3": metrics.foot_jerk(e.pinned, skeleton, fps, units_per_meter=upm)}),
        **{f"sliding_{k.replace(', ', '_')}": v for k, v in sliding_sources(e, skeleton, fps).items()},
    }


def capture_clip(subject: Subject, fps: float = 60.0) -> Motion:
    """The style's capture: the first clip of its start rows
    (:func:`jaxstyle.data.datasets.style_rows`: a forward walk, else a forward run, of the style;
    never a backward or sideways take while it has a forward one), as the paths move forward."""
    return datasets.load_clip(capture_spec(subject.dataset, subject.style), fps=fps)


def capture_spec(dataset: datasets.Dataset, style: str):
    """The clip spec of a style's capture row (:func:`capture_clip`)."""
    return dataset.specs[int(dataset.clip[style_rows(dataset, style)[0]])]


def capture_row(subject: Subject) -> dict:
    """The same figures for the style's capture (forward kinematics of the BVH; no path), naming
    the file in ``capture_file``."""
    spec = capture_spec(subject.dataset, subject.style)
    return {"model": subject.model, "style": subject.title, "kind": subject.kind, "path": "capture",
            "capture_file": Path(spec.path).name, **capture_figures(datasets.load_clip(spec, fps=60.0))}


def capture_figures(clip: Motion) -> dict:
    """:func:`measure`'s figures of real motion (its skeleton is its BVH: the network, BVH and
    locked columns are the same, the lock moved nothing; the floor is its own; no path, so the
    path figures are NaN)."""
    upm, fps = estimate_units_per_meter(clip), clip.fps
    pos = global_positions(clip)
    q = metrics.motion_quality(pos, clip, fps, units_per_meter=upm)
    skate = q.foot_skating_m_s
    jerk = metrics.foot_jerk(pos, clip, fps, units_per_meter=upm)
    steps = metrics.step_figures(pos, clip, fps)
    nan = float("nan")
    return {"speed_m_s": nan, "finite": True,
            "foot_skating_m_s": skate, "foot_skating_bvh_m_s": skate, "foot_skating_locked_m_s": skate,
            "contact_fraction": q.contact_fraction, **dataclasses.asdict(steps), "steps_per_s_bvh": steps.steps_per_s,
            "ik_foot_offset_max_m": 0.0,
            "foot_below_floor_m": metrics.foot_below_floor_m(pos, clip, footlock.skeleton_floor(clip),
                                                             units_per_meter=upm),
            "bone_error_mean": q.bone_error_mean,
            "bone_error_max": q.bone_error_max, "bone_error_bvh_max": q.bone_error_max, "joint_difference_max_m": 0.0,
            "path_error_mean_m": nan, "path_error_final_m": nan, "path_error_final_pct": nan,
            "heading_error_deg": nan, "stop_time_s": nan, "jitter_m_s3": q.jitter_m_s3, "ankle_jerk_m_s3": jerk,
            "ankle_jerk_bvh_m_s3": jerk, "ankle_jerk_locked_m_s3": jerk}


def _model(r: dict) -> str:
    return r.get("model") or MODEL_2018


def _capture_of(rows: list[dict]) -> dict[tuple[str, str], dict]:
    """The capture row of each ``(model, style)``."""
    return {(_model(r), r["style"]): r for r in rows if r["path"] == "capture"}


LOCK_TARGETS = ("locked skating <= capture + 0.03", "foot offset <= 0.15 m", "foot below floor <= 0.01 m",
                "steps/s within 25% of capture", "stance fraction within 0.15 of capture",
                "locked ankle jerk <= 1.5x capture")
"""The foot-locking targets :func:`targets` checks (their names), beside :data:`PATH_TARGETS`."""


def targets(rows: list[dict]) -> list[dict]:
    """One entry per (target, character, path): ``{"target", "model", "style", "path", "value",
    "limit", "met"}``. Against the style's capture: raw skating (1.5x for base styles, 2x for
    few-shot) and :data:`LOCK_TARGETS` (skating after locking at most the capture's + 0.03 m/s,
    ``steps_per_s`` within 25% and ``stance_fraction`` within 0.15 of the capture's, ankle jerk
    after locking at most 1.5x; the value of the two "within" targets is the difference from the
    capture); on every row: no foot moved more than 0.15 m by the lock, none more than 1 cm below
    the floor; final path error <= 0.3 m on straight, circle and zigzag, stop within 0.5 s, BVH bone
    error 0."""
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
            "ankle jerk net / locked m/s^3 |")
    lines = [head, "|" + "---|" * 15]
    order = {m: i for i, m in enumerate(dict.fromkeys(_model(r) for r in rows))}
    for r in sorted(rows, key=lambda r: (order[_model(r)], r["style"], r["path"] != "capture")):
        g = r.get
        path = f"capture ({r['capture_file']})" if r["path"] == "capture" and g("capture_file") else r["path"]
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
            f"{_f(g('ankle_jerk_m_s3'), 0)} / {_f(g('ankle_jerk_locked_m_s3'), 0)} |")
    return lines


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

def _one_clip_rows(dataset: datasets.Dataset, style: str) -> np.ndarray:
    rows = style_rows(dataset, style)
    clip = dataset.clip[rows[0]]
    rows = rows[dataset.clip[rows] == clip]
    return rows[np.argsort(dataset.frame[rows])]


def outputs_positions(outputs_NxO: np.ndarray, num_joints: int) -> np.ndarray:
    """``(N, J, 3)`` global joint positions of a sequence of de-normalised PFNN outputs: the root
    motion integrated from the origin facing +Z, each frame's local joint positions placed there
    (what the closed loop does, without feeding anything back)."""
    y = np.asarray(outputs_NxO, dtype=np.float64)
    g = PFNNLayout(num_joints).output_groups
    n = len(y)
    yaw = np.cumsum(y[:, 2])
    prev = np.concatenate([[0.0], yaw[:-1]])
    gx, gz = y[:, 0] * np.cos(prev) + y[:, 1] * np.sin(prev), -y[:, 0] * np.sin(prev) + y[:, 1] * np.cos(prev)
    origin = np.cumsum(np.stack([gx, gz], axis=1), axis=0)
    local = y[:, g["joint_position"]].reshape(n, num_joints, 3)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    wx, wz = local[..., 0] * c + local[..., 2] * s, -local[..., 0] * s + local[..., 2] * c
    return np.stack([wx + origin[:, :1], local[..., 1], wz + origin[:, 1:]], axis=-1)


def _root_vs_foot(outputs_NxO, positions_NxJx3, skeleton: Motion, fps: float, upm: float) -> dict:
    """On frames where a foot joint stays within 1 cm of its floor: the root's speed, the speed of
    that foot in the character frame (it should move backwards as fast as the root moves forward)
    and the foot's world speed (the skating)."""
    y = np.asarray(outputs_NxO, dtype=np.float64)
    g = PFNNLayout(skeleton.num_joints).output_groups
    feet = FootJoints.find(skeleton)
    joints = list(feet.ankles) + list(feet.toes)
    local = y[:, g["joint_position"]].reshape(len(y), -1, 3)[:, joints]
    h = local[..., 1]
    on = h <= np.percentile(h, 5, axis=0) + metrics.TOLERANCE_M * upm
    both = on[1:] & on[:-1]
    root = np.repeat(np.linalg.norm(y[1:, :2], axis=-1)[:, None], len(joints), axis=1) * fps / upm
    foot_local = np.linalg.norm(np.diff(local[..., [0, 2]], axis=0), axis=-1) * fps / upm
    world = np.linalg.norm(np.diff(np.asarray(positions_NxJx3)[:, joints][..., [0, 2]], axis=0), axis=-1) * fps / upm
    return {"root_m_s": float(root[both].mean()), "planted_foot_local_m_s": float(foot_local[both].mean()),
            "planted_foot_world_m_s": float(world[both].mean())}


def diagnose(params: dict, normalisers: tuple[Normaliser, Normaliser], subject: Subject, skeleton: Motion) -> dict:
    """Where sliding and drift come from, for one subject (``docs/quality.md``):

    * ``teacher_forced``: skating, bone error and jitter of the network's one-step predictions from
      real inputs along one capture clip (the real root motion, the predicted pose), against the
      capture's own rows and the closed loop (``closed_loop``: straight path, own speed, with the
      path-following law);
    * ``root_vs_foot``: on planted frames, the root's speed vs the planted foot's backward speed in
      the character frame (equal when a foot does not slide) and its world speed, for the capture
      rows and the closed loop;
    * ``phase``: phase advance (cycles/s) of the capture, of the teacher-forced prediction and of the
      closed loop;
    * ``blending``: final path error and skating on straight and zigzag for trajectory blend biases
      0.5 / 1.5 / 3.0, with and without the path-following law;
    * ``normalisation``: the output standard deviations of root velocity, turn, phase change and
      joint positions (m or rad per frame) and the teacher-forced RMSE of each in units of them.
    """
    ds = subject.dataset
    x_norm, y_norm = normalisers
    upm, fps, J = estimate_units_per_meter(skeleton), skeleton.fps, skeleton.num_joints
    g = PFNNLayout(J).output_groups
    rows = _one_clip_rows(ds, subject.style)
    x = jnp.asarray(x_norm.apply(ds.inputs[rows]), jnp.float32)
    y_pred = y_norm.invert(np.asarray(pfnn.pfnn_apply(params, x, jnp.asarray(ds.phases[rows, 0]),
                                                      adapter=subject.conditioning), dtype=np.float64))
    y_real = np.asarray(ds.outputs[rows], dtype=np.float64)
    hybrid = y_real.copy()
    hybrid[:, g["joint_position"]] = y_pred[:, g["joint_position"]]
    out: dict = {"style": subject.title, "rows": int(len(rows))}

    def q(pos):
        m = metrics.motion_quality(pos, skeleton, fps, units_per_meter=upm)
        return {"skating_m_s": m.foot_skating_m_s, "bone_error_mean": m.bone_error_mean, "jitter_m_s3": m.jitter_m_s3}

    out["capture_rows"] = q(outputs_positions(y_real, J))
    out["teacher_forced"] = q(outputs_positions(hybrid, J))
    model = PFNNModel.create(params, normalisers, J)
    start_rows = style_rows(ds, subject.style)
    speed = model.own_speed(ds, start_rows, upm, fps)
    start = loop.start_row(ds.inputs, speed, units_per_meter=upm, rows=start_rows, fps=fps)
    state = model.initial_state(ds, start)
    blending = {}
    closed = None
    for follow in (None, loop.FOLLOW_SECONDS):
        for bias in (0.5, 1.5, 3.0):
            for name in ("straight", "zigzag"):
                sig = paths.named(name, SECONDS, speed, units_per_meter=upm, fps=fps)
                r = jax.tree.map(np.asarray, rollout(
                    model.replace(blend_bias=bias), subject.conditioning, state,
                    loop.signal_controls(sig, follow_seconds=follow)))
                err = np.linalg.norm(r.origin - sig.positions, axis=-1)[-1] / upm
                skate = metrics.foot_skating(r.positions, skeleton, fps, units_per_meter=upm)
                blending[f"{name}, bias {bias:g}, {'follow' if follow else 'open loop'}"] = (float(err), skate)
                if follow and bias == 1.5 and name == "straight":
                    closed = r
    out["blending"] = blending
    out["closed_loop"] = q(closed.positions)
    out["root_vs_foot"] = {"capture": _root_vs_foot(y_real, outputs_positions(y_real, J), skeleton, fps, upm),
                           "closed_loop": _root_vs_foot(closed.outputs, closed.positions, skeleton, fps, upm)}
    out["phase"] = {"capture": float(np.mean(y_real[:, 3]) * fps), "teacher_forced": float(np.mean(y_pred[:, 3]) * fps),
                    "closed_loop": float(np.mean(np.mod(np.diff(closed.phase), 1.0)) * fps)}
    walked = float(np.mean(np.linalg.norm(np.diff(closed.origin, axis=0), axis=-1)) * fps / upm)
    out["speed_m_s"] = {"requested": speed, "closed_loop": walked}
    norm = {}
    for key, sl, unit in (("root velocity (m/frame)", g["root_velocity"], upm), ("turn (rad/frame)",
                          g["root_angular_velocity"], 1.0), ("phase change (cycles/frame)", g["phase_change"], 1.0),
                          ("joint positions (m)", g["joint_position"], upm)):
        std = float(np.mean(y_norm.std[sl]))
        rmse = float(np.sqrt(np.mean((y_pred[:, sl] - y_real[:, sl]) ** 2)))
        norm[key] = (std / unit, rmse / std)
    out["normalisation"] = norm
    return out


def diagnosis_lines(d: dict) -> list[str]:
    """Markdown lines of :func:`diagnose`'s figures."""
    lines = [f"**{d['style']}** ({d['rows']} capture rows of one clip)", "",
             "| motion | skating m/s | bone error mean | jitter m/s^3 |", "|---|---|---|---|"]
    for k, label in (("capture_rows", "capture rows"), ("teacher_forced", "teacher-forced (real root, predicted pose)"),
                     ("closed_loop", "closed loop (straight, following)")):
        v = d[k]
        lines.append(f"| {label} | {v['skating_m_s']:.3f} | {100 * v['bone_error_mean']:.1f}% "
                     f"| {v['jitter_m_s3']:.0f} |")
    lines += ["", "| planted frames | root m/s | planted foot, character frame m/s | planted foot, world m/s |",
              "|---|---|---|---|"]
    for k, v in d["root_vs_foot"].items():
        lines.append(f"| {k} | {v['root_m_s']:.3f} | {v['planted_foot_local_m_s']:.3f} | "
                     f"{v['planted_foot_world_m_s']:.3f} |")
    p, s = d["phase"], d["speed_m_s"]
    lines += ["", f"phase advance (cycles/s): capture {p['capture']:.3f}, teacher-forced {p['teacher_forced']:.3f}, "
              f"closed loop {p['closed_loop']:.3f}; speed requested {s['requested']:.2f} m/s, closed loop "
              f"{s['closed_loop']:.2f} m/s", "", "| path, blend bias, law | final path error m | skating m/s |",
              "|---|---|---|"]
    lines += [f"| {k} | {e:.2f} | {sk:.3f} |" for k, (e, sk) in d["blending"].items()]
    lines += ["", "| output group | std (m, rad or cycles) | teacher-forced RMSE / std |", "|---|---|---|"]
    lines += [f"| {k} | {std:.4f} | {r:.2f} |" for k, (std, r) in d["normalisation"].items()]
    return lines


SLIDING_SOURCES = ("held", "easing", "free, slow", "free, fast")
"""Where the skating left after foot locking comes from (:func:`sliding_sources`)."""


def sliding_sources(e: Exported, skeleton: Motion, fps: float) -> dict[str, float]:
    """Split the skating of the locked skeleton (:func:`jaxstyle.output.metrics.foot_skating`: the
    horizontal travel of heels and toes over frame steps they spend within 1 cm of their floor) by
    what the lock was doing with that point: ``held`` (locked in both frames), ``easing`` (free,
    its offset from a release or hand-over still decaying, over 1 mm), ``free, slow`` (free, the
    network's point slower than the touch-down speed) and ``free, fast`` (free, the network's point
    moving along the floor faster than a contact may start). Returns each share of the total
    travel (summing to 1; NaN without such steps)."""
    feet = FootJoints.find(skeleton)
    locked_pts = footlock.points_of(e.locked, feet)  # (T, 2, 2, 3)
    net_pts = footlock.points_of(e.bvh, feet)
    h = locked_pts[..., 1]
    on = h <= np.percentile(h, 5, axis=0) + metrics.TOLERANCE_M * estimate_units_per_meter(skeleton)
    planted = on[1:] & on[:-1]
    travel = np.linalg.norm(np.diff(locked_pts[..., [0, 2]], axis=0), axis=-1)
    held = e.lock.frames.locked[1:] & e.lock.frames.locked[:-1]
    drawn = np.stack([e.lock.frames.ankle, e.lock.frames.toe], axis=2)
    body = body_units_per_meter(skeleton, feet)
    easing = np.linalg.norm(drawn - net_pts, axis=-1)[1:] > 0.001 * body
    speed = np.linalg.norm(np.diff(net_pts[..., [0, 2]], axis=0), axis=-1) * fps / body
    fast = speed >= footlock.FootLockConfig().speed_on_m_s
    parts = {"held": held, "easing": ~held & easing, "free, slow": ~held & ~easing & ~fast,
             "free, fast": ~held & ~easing & fast}
    total = float(np.sum(travel[planted]))
    return {k: float(np.sum(travel[planted & m])) / total if total > 0 else float("nan") for k, m in parts.items()}


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
              "within 1 cm of the floor, :func:`jaxstyle.output.quality.sliding_sources`):", "",
              "| model | " + " | ".join(SLIDING_SOURCES) + " |", "|---|" + "---|" * len(SLIDING_SOURCES)]
    for model in dict.fromkeys(_model(r) for r in rows):
        mine = [r for r in rows if _model(r) == model and r["path"] != "capture" and "sliding_held" in r]
        if mine:
            shares = [_f(float(np.nanmedian([r[f"sliding_{k.replace(', ', '_')}"] for r in mine])))
                      for k in SLIDING_SOURCES]
            lines.append(f"| {model} | " + " | ".join(shares) + " |")
    return lines
