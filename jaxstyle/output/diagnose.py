"""Where the 2018 PFNN's sliding and drift come from, for one character (``docs/quality.md``): the
network's one-step predictions from real inputs against the capture's rows and the closed loop,
root against planted-foot velocity, phase advance, trajectory blending with and without the
path-following law, and the output normalisation (:func:`diagnose`, :func:`diagnosis_lines`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop, paths
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.model import rollout
from jaxstyle.data import datasets
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.labels.contacts import FootJoints, estimate_units_per_meter
from jaxstyle.motion import Motion
from jaxstyle.nn import pfnn
from jaxstyle.output import metrics
from jaxstyle.output.quality import SECONDS, Subject


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
