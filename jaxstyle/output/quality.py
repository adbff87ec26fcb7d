"""The motion-quality benchmark of ``experiments/quality.py`` (issue 19): every character along the
six protocol paths, measured as the user sees it, beside the same figures of its style's capture.

Per (character, path), from ONE batched closed-loop rollout with the path-following law of
:mod:`jaxstyle.control.loop` (:func:`run` for the 2018 PFNN with style adapters, :func:`run_lpn` for
the 2022 style models; both measured by the one function :func:`measure`):

* foot skating (:func:`jaxstyle.output.metrics.foot_skating`) of the network's own joints, of the
  exported skeleton (the BVH's forward kinematics: bone lengths exact, :mod:`jaxstyle.output.export`)
  and of the exported skeleton after contact IK (:func:`jaxstyle.output.export.fix_feet`: the
  network's predicted heel and toe contacts when the model has the 2018 layout's contact outputs);
* feet on the floor, bone error of the network's joints and of the BVH (0 by construction), and
  the largest distance between the network's joints and the BVH's;
* path error (mean, final, final as % of the path's length), heading error, the time to stop
  after each stop command (:func:`jaxstyle.output.metrics.stop_times`), jitter and ankle jerk.

:func:`capture_row` gives the same figures for a clip of the style's capture (no path: those are
blank). Every row names its ``model`` (:data:`MODEL_2018` or the 2022 model's Table 2 name).
:func:`targets` checks the issue's targets, :func:`table` and :func:`write_csv` report,
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
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import controller, loop, lpn_controller, paths
from jaxstyle.data import datasets
from jaxstyle.data.lpn_features import LPNLayout, end_effector_columns
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.labels.contacts import FootJoints, estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.motion.kinematics import global_positions
from jaxstyle.nn import pfnn
from jaxstyle.output import export, lpn_synthesis, metrics
from jaxstyle.output.synthesis import own_speed, stack_trees, start_states, style_rows

PROTOCOL_PATHS = ("straight", "circle", "zigzag", "stop_and_go", "speed_ramp", "waypoints")
FOLLOW_PATHS = ("straight", "circle", "zigzag")  # the paths of the 0.3 m final-error target
TARGET_PATHS = FOLLOW_PATHS + ("stop_and_go",)  # the paths of the path and stop targets (``jaxstyle demo``)
PATH_TARGETS = ("final path error <= 0.3 m", "stop within 0.5 s")  # their names in :func:`targets`
SECONDS = 8.0
MODEL_2018 = "2018 PFNN"
"""The ``model`` of the 2018 characters' rows (the 2022 models' rows carry their Table 2 names)."""


@dataclasses.dataclass(frozen=True)
class Subject:
    """One character: ``title``, ``kind`` (``"base"`` or ``"few-shot"``), its ``adapter`` (the 2018
    PFNN's residual adapter; for a 2022 model the runtime style that
    :func:`jaxstyle.nn.style_models.model_apply` takes: a FiLM vector, one-hot row or adapter, as in
    :class:`jaxstyle.output.lpn_synthesis.LPNCharacter`), the ``dataset`` + ``style`` whose rows give
    its start pose, its own speed and its capture, and the ``model`` it belongs to."""

    title: str
    kind: str
    adapter: Any
    dataset: datasets.Dataset
    style: str
    model: str = MODEL_2018


def subject(character, kind: str, model: str = MODEL_2018) -> Subject:
    """The :class:`Subject` of a synthesis character: a 2018
    :class:`jaxstyle.output.synthesis.Character` (its ``adapter``) or a 2022
    :class:`jaxstyle.output.lpn_synthesis.LPNCharacter` (its ``runtime`` style)."""
    style = character.runtime if isinstance(character, lpn_synthesis.LPNCharacter) else character.adapter
    return Subject(character.title, kind, style, character.dataset, character.style, model)


Drawn = dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]


def _drive(subjects: Sequence[Subject], skeleton: Motion, initial, rollout_batch, *, speed_of,
           path_names: Sequence[str], seconds: float, follow_seconds: float | None, blend_frames: int
           ) -> tuple[list[dict], Drawn]:
    """What :func:`run` and :func:`run_lpn` share: the start states
    (:func:`jaxstyle.output.synthesis.start_states`, the style's own median speed by ``speed_of``,
    ``initial(subject, dataset, row)``), the path signals and controls with the
    path-following law, ONE batched rollout (``rollout_batch(which, states, controls)``, ``which``
    the subject of each rollout), then :func:`measure_rollouts`."""
    upm, fps = estimate_units_per_meter(skeleton), skeleton.fps
    starts, speeds = start_states(subjects, upm, fps, initial, speed_of=speed_of)
    pairs = [(i, p) for i in range(len(subjects)) for p in path_names]
    signals = [paths.named(p, seconds, speeds[i], units_per_meter=upm, fps=fps) for i, p in pairs]
    which = [i for i, _ in pairs]
    out = rollout_batch(which, stack_trees([starts[i] for i in which]),
                        stack_trees([loop.signal_controls(sig, follow_seconds=follow_seconds) for sig in signals]))
    return measure_rollouts(subjects, pairs, signals, out, skeleton, speeds, blend_frames=blend_frames)


def measure_rollouts(subjects: Sequence[Subject], pairs: Sequence[tuple[int, str]], signals: Sequence[paths.PathSignal],
                     rollouts, skeleton: Motion, speeds: Sequence[float], *, blend_frames: int = 5
                     ) -> tuple[list[dict], Drawn]:
    """:func:`measure` each rollout of a batch of either controller (leading axis ``len(pairs)``,
    ``pairs[k] = (subject index, path name)`` along ``signals[k]``), then one :func:`capture_row`
    per subject. Returns the rows and, per ``(title, path)``, the network's joint positions (the
    skeleton's joints) and the path's ideal positions (previews)."""
    upm = estimate_units_per_meter(skeleton)
    out = jax.tree.map(np.asarray, rollouts)
    results, drawn = [], {}
    for k, (i, p) in enumerate(pairs):
        one = jax.tree.map(lambda v, k=k: v[k], out)
        s = subjects[i]
        drawn[(s.title, p)] = (one.positions[:, :skeleton.num_joints], signals[k].positions)
        row = measure(one, skeleton, signals[k], units_per_meter=upm, blend_frames=blend_frames)
        results.append({"model": s.model, "style": s.title, "kind": s.kind, "path": p, "speed_m_s": speeds[i], **row})
    for s in subjects:
        results.append(capture_row(s))
    return results, drawn


def run(params: dict, normalisers: tuple[Normaliser, Normaliser], subjects: Sequence[Subject], skeleton: Motion, *,
        path_names: Sequence[str] = PROTOCOL_PATHS, seconds: float = SECONDS,
        follow_seconds: float | None = loop.FOLLOW_SECONDS, blend_frames: int = 5, blend_bias: float = 1.5
        ) -> tuple[list[dict], Drawn]:
    """Drive every subject (2018 PFNN adapters) along every path at its style's own median speed
    (one batched rollout, :func:`jaxstyle.control.controller.rollout_batch`) and :func:`measure`
    each; then one :func:`capture_row` per subject. Returns the rows and, per ``(title, path)``, the
    network's joint positions and the path's ideal positions (previews)."""
    x_norm, y_norm = normalisers

    def initial(_, ds, row):
        return controller.initial_state(ds.inputs[row], float(ds.phases[row, 0]), skeleton.num_joints)

    def rollout_batch(which, states, controls):
        adapters = pfnn.stack_adapters([subjects[i].adapter for i in which])
        return controller.rollout_batch(params, adapters, x_norm, y_norm, states, controls, blend_bias=blend_bias)

    return _drive(subjects, skeleton, initial, rollout_batch, speed_of=own_speed, path_names=path_names,
                  seconds=seconds, follow_seconds=follow_seconds, blend_frames=blend_frames)


def run_lpn(params: dict, config, normalisers: tuple[Normaliser, Normaliser], subjects: Sequence[Subject],
            skeleton: Motion, *, path_names: Sequence[str] = PROTOCOL_PATHS, seconds: float = SECONDS,
            follow_seconds: float | None = loop.FOLLOW_SECONDS, blend_frames: int = 5, blend_bias: float = 1.5
            ) -> tuple[list[dict], Drawn]:
    """:func:`run` for a trained 2022 style model (Mason, Starke & Komura 2022, section 4.4): the
    subjects' ``adapter`` is their runtime style, driven by
    :func:`jaxstyle.control.lpn_controller.rollout_batch` from a real pose of the style with its
    local phases, at the style's own speed (:func:`jaxstyle.output.lpn_synthesis.own_speed`), as
    :func:`jaxstyle.output.lpn_synthesis.synthesize` starts its characters; the same paths, the
    same path-following law and the same :func:`measure` as the 2018 characters. ``config``: the
    model's :class:`jaxstyle.nn.style_models.StyleModelConfig`; ``normalisers``: its training
    data's. Every backbone: the MANN's gating columns come from ``skeleton``; the PFNN backbone's
    global phase starts at the row's and advances at the rate
    :func:`jaxstyle.control.lpn_controller.phase_ratio` fits for the subject's style and runtime
    style, as :func:`jaxstyle.output.lpn_synthesis.synthesize` starts it."""
    x_norm, y_norm = normalisers
    num_bones = LPNLayout.of_inputs(subjects[0].dataset.inputs.shape[1]).num_bones
    gate_columns = end_effector_columns(skeleton) if config.backbone == "mann" else None

    def initial(s, ds, row):
        return lpn_synthesis.start_state(ds, row, num_bones, lpn_synthesis.style_phase_ratio(
            params, config, s.adapter, normalisers, ds, s.style, gate_columns=gate_columns))

    def rollout_batch(which, states, controls):
        return lpn_controller.rollout_batch(params, config, stack_trees([subjects[i].adapter for i in which]), x_norm,
                                            y_norm, states, controls, gate_columns=gate_columns, blend_bias=blend_bias)

    return _drive(subjects, skeleton, initial, rollout_batch, speed_of=lpn_synthesis.own_speed,
                  path_names=path_names, seconds=seconds, follow_seconds=follow_seconds, blend_frames=blend_frames)


def measure(rollout: controller.Rollout | lpn_controller.LPNRollout, skeleton: Motion, signal: paths.PathSignal, *,
            units_per_meter: float, blend_frames: int = 5) -> dict:
    """The figures of one character's rollout along ``signal`` (see the module docstring), of either
    controller: the network's joints are the skeleton's (an LPN rollout's extra hand points are left
    out), the exported skeleton is the BVH's (:func:`jaxstyle.output.export.rollout_motion` decodes
    both models' outputs), the IK uses the network's own contacts when it predicts them."""
    upm, fps = float(units_per_meter), float(signal.fps)
    net = np.asarray(rollout.positions, dtype=np.float64)[:, :skeleton.num_joints]
    nan = float("nan")
    row = {"foot_skating_m_s": nan, "foot_skating_bvh_m_s": nan, "foot_skating_ik_m_s": nan}
    if not np.isfinite(np.asarray(rollout.outputs)).all():
        return {**row, "finite": False}
    motion = export.rollout_motion(rollout, skeleton)
    bvh = global_positions(motion)
    after = global_positions(export.fix_feet(motion, rollout, blend_frames=blend_frames))
    bones = metrics.bone_length_errors(net, skeleton)
    err = np.linalg.norm(np.asarray(rollout.origin) - signal.positions, axis=-1) / upm
    length = float(np.sum(np.linalg.norm(signal.velocity, axis=1)) / fps / upm)
    stops = metrics.stop_times(rollout.origin, signal.velocity, fps, units_per_meter=upm)
    q = metrics.motion_quality(net, skeleton, fps, units_per_meter=upm)
    return {
        "finite": True,
        "foot_skating_m_s": metrics.foot_skating(net, skeleton, fps, units_per_meter=upm),
        "foot_skating_bvh_m_s": metrics.foot_skating(bvh, skeleton, fps, units_per_meter=upm),
        "foot_skating_ik_m_s": metrics.foot_skating(after, skeleton, fps, units_per_meter=upm),
        "contact_fraction": q.contact_fraction,
        "bone_error_mean": float(np.mean(bones)), "bone_error_max": float(np.max(bones)),
        "bone_error_bvh_max": float(np.max(metrics.bone_length_errors(bvh, skeleton))),
        "joint_difference_max_m": metrics.max_joint_difference_m(net, bvh, units_per_meter=upm),
        "path_error_mean_m": float(np.mean(err)), "path_error_final_m": float(err[-1]),
        "path_error_final_pct": 100.0 * float(err[-1]) / length if length > 0 else nan,
        "heading_error_deg": metrics.heading_error_deg(rollout.yaw, signal.yaw),
        "stop_time_s": float(np.max(stops)) if len(stops) else nan, "stop_commands": int(len(stops)),
        "jitter_m_s3": q.jitter_m_s3,
        "ankle_jerk_m_s3": metrics.foot_jerk(net, skeleton, fps, units_per_meter=upm),
        "ankle_jerk_ik_m_s3": metrics.foot_jerk(after, skeleton, fps, units_per_meter=upm),
    }


def capture_clip(subject: Subject, fps: float = 60.0) -> Motion:
    """The first clip of the subject's style (its walking clips when it has some)."""
    spec = subject.dataset.specs[int(subject.dataset.clip[style_rows(subject.dataset, subject.style)[0]])]
    return datasets.load_clip(spec, fps=fps)


def capture_row(subject: Subject) -> dict:
    """The same figures for the style's capture (forward kinematics of the BVH; no path)."""
    return {"model": subject.model, "style": subject.title, "kind": subject.kind, "path": "capture",
            **capture_figures(capture_clip(subject))}


def capture_figures(clip: Motion) -> dict:
    """:func:`measure`'s figures of real motion (its skeleton is its BVH: the network, BVH and IK
    columns are the same; no path, so the path figures are NaN)."""
    upm, fps = estimate_units_per_meter(clip), clip.fps
    pos = global_positions(clip)
    q = metrics.motion_quality(pos, clip, fps, units_per_meter=upm)
    skate = q.foot_skating_m_s
    jerk = metrics.foot_jerk(pos, clip, fps, units_per_meter=upm)
    nan = float("nan")
    return {"speed_m_s": nan, "finite": True,
            "foot_skating_m_s": skate, "foot_skating_bvh_m_s": skate, "foot_skating_ik_m_s": skate,
            "contact_fraction": q.contact_fraction, "bone_error_mean": q.bone_error_mean,
            "bone_error_max": q.bone_error_max, "bone_error_bvh_max": q.bone_error_max, "joint_difference_max_m": 0.0,
            "path_error_mean_m": nan, "path_error_final_m": nan, "path_error_final_pct": nan,
            "heading_error_deg": nan, "stop_time_s": nan, "jitter_m_s3": q.jitter_m_s3, "ankle_jerk_m_s3": jerk,
            "ankle_jerk_ik_m_s3": jerk}


def _model(r: dict) -> str:
    return r.get("model") or MODEL_2018


def _capture_of(rows: list[dict]) -> dict[tuple[str, str], dict]:
    """The capture row of each ``(model, style)``."""
    return {(_model(r), r["style"]): r for r in rows if r["path"] == "capture"}


def targets(rows: list[dict]) -> list[dict]:
    """One entry per (target, character, path) of the issue: ``{"target", "model", "style", "path",
    "value", "limit", "met"}``; skating targets against the style's capture (1.5x for base styles, 2x for
    few-shot; after IK the capture's + 0.03 m/s, ankle jerk at most 1.5x the capture's), final path
    error <= 0.3 m on straight, circle and zigzag, stop within 0.5 s, BVH bone error 0."""
    cap = _capture_of(rows)
    out = []

    def add(name, r, value, limit):
        met = bool(np.isfinite(value) and value <= limit)
        out.append({"target": name, "model": _model(r), "style": r["style"], "path": r["path"], "value": value,
                    "limit": limit, "met": met})

    for r in rows:
        if r["path"] == "capture":
            continue
        c = cap.get((_model(r), r["style"]))
        if c is not None:
            factor = 1.5 if r["kind"] == "base" else 2.0
            add(f"raw skating <= {factor:g}x capture", r, r["foot_skating_m_s"], factor * c["foot_skating_m_s"])
            add("IK skating <= capture + 0.03", r, r["foot_skating_ik_m_s"], c["foot_skating_m_s"] + 0.03)
            add("IK ankle jerk <= 1.5x capture", r, r["ankle_jerk_ik_m_s3"], 1.5 * c["ankle_jerk_m_s3"])
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
    with its value, its limit and a pass/FAIL mark, then one line counting them."""
    mine = [c for c in checks if c["target"] in names]
    lines = ["| model | style | path | target | value | limit | |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {c.get('model', MODEL_2018)} | {c['style']} | {c['path']} | {c['target']} | {_f(c['value'], 2)} | "
              f"{_f(c['limit'], 2)} | {'pass' if c['met'] else 'FAIL'} |" for c in mine]
    met = sum(c["met"] for c in mine)
    blank = sum(not np.isfinite(c["value"]) for c in mine)
    note = f" ({blank} n/a: never stopped before the path moved on or ended, or a diverged rollout)" if blank else ""
    return lines + ["", f"{', '.join(names)}: {met} of {len(mine)} met{note}"]


def _f(v, digits: int = 2) -> str:
    return "n/a" if v is None or not np.isfinite(v) else f"{v:.{digits}f}"


def table(rows: list[dict]) -> list[str]:
    """The benchmark's markdown table: per model (in order of appearance) and style, its capture
    row, then one row per path."""
    head = ("| model | style | path | skating m/s net / BVH / IK | feet on floor | bone error net max / BVH | "
            "joint diff m | path error mean / final m (final %) | heading deg | stop s | jitter m/s^3 | "
            "ankle jerk net / IK m/s^3 |")
    lines = [head, "|" + "---|" * 12]
    order = {m: i for i, m in enumerate(dict.fromkeys(_model(r) for r in rows))}
    for r in sorted(rows, key=lambda r: (order[_model(r)], r["style"], r["path"] != "capture")):
        lines.append(
            f"| {_model(r)} | {r['style']} | {r['path']} | {_f(r['foot_skating_m_s'])} / "
            f"{_f(r['foot_skating_bvh_m_s'])} / "
            f"{_f(r['foot_skating_ik_m_s'])} | {_f(r.get('contact_fraction'))} | "
            f"{100 * r.get('bone_error_max', math.nan):.1f}% / {100 * r.get('bone_error_bvh_max', math.nan):.1g}%"
            f" | {_f(r.get('joint_difference_max_m'))} | {_f(r.get('path_error_mean_m'))} / "
            f"{_f(r.get('path_error_final_m'))} ({_f(r.get('path_error_final_pct'), 1)}%) | "
            f"{_f(r.get('heading_error_deg'), 1)} | {_f(r.get('stop_time_s'))} | {_f(r.get('jitter_m_s3'), 0)} | "
            f"{_f(r.get('ankle_jerk_m_s3'), 0)} / {_f(r.get('ankle_jerk_ik_m_s3'), 0)} |")
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


PLOTTED = (("foot_skating_m_s", "skating, network joints (m/s)"), ("foot_skating_ik_m_s", "skating after IK (m/s)"),
           ("contact_fraction", "feet on floor"), ("jitter_m_s3", "jitter (m/s^3)"),
           ("ankle_jerk_ik_m_s3", "ankle jerk after IK (m/s^3)"))


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
                                                      adapter=subject.adapter), dtype=np.float64))
    y_real = np.asarray(ds.outputs[rows], dtype=np.float64)
    hybrid = y_real.copy()
    hybrid[:, g["joint_position"]] = y_pred[:, g["joint_position"]]
    out: dict = {"style": subject.title, "rows": int(len(rows))}

    def q(pos):
        m = metrics.motion_quality(pos, skeleton, fps, units_per_meter=upm)
        return {"skating_m_s": m.foot_skating_m_s, "bone_error_mean": m.bone_error_mean, "jitter_m_s3": m.jitter_m_s3}

    out["capture_rows"] = q(outputs_positions(y_real, J))
    out["teacher_forced"] = q(outputs_positions(hybrid, J))
    speed = own_speed(ds, style_rows(ds, subject.style), upm, fps)
    start_rows = style_rows(ds, subject.style)
    start = controller.start_row(ds.inputs, speed, units_per_meter=upm, rows=start_rows, fps=fps)
    state = controller.initial_state(ds.inputs[start], float(ds.phases[start, 0]), J)
    blending = {}
    closed = None
    for follow in (None, loop.FOLLOW_SECONDS):
        for bias in (0.5, 1.5, 3.0):
            for name in ("straight", "zigzag"):
                sig = paths.named(name, SECONDS, speed, units_per_meter=upm, fps=fps)
                r = jax.tree.map(np.asarray, controller.rollout(
                    params, subject.adapter, x_norm, y_norm, state, loop.signal_controls(sig, follow_seconds=follow),
                    blend_bias=bias))
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
