"""Why the 2022 closed loop freezes, and what each remedy does: the same data, the same model size,
trained by each recipe, driven with the paper's runtime and with the local phases floored.

    python experiments/mason2022_closed_loop.py [--epochs 4] [--run runs/closed_loop] [--seeds 0 1 2]

Protocol (fixed):

1. Data: the demo's 2022 data, the shared 100STYLE sample's paper base styles (Angry, Chicken,
   Drunk, InTheDark, Neutral; every locomotion gait, mirrored), LPN rows
   (:func:`jaxstyle.mason2022.pipeline.build_data`).
2. Models: LPN-FiLM at the demo's size (256 hidden units, a FiLM generator of 32 filters and 512
   dense units), ``--epochs`` epochs at Adam 1e-3 (the demo's rate), one per recipe
   (:class:`jaxstyle.mason2022.train.LPNTrainConfig`): ``paper`` (the paper's losses),
   ``noise`` (``input_noise`` 1.0 on the normalised inputs), ``rollout`` (``rollout_steps``
   4: windows of 5 frames fed the network's own outputs), ``contact1`` and ``contact10``
   (``contact_loss_weight`` 1 and 10: :func:`jaxstyle.mason2022.loss.contact_loss`, planted
   feet do not move) and ``rollout_contact10`` (both: the contact loss on the network's own
   fed-back frames too). ``--seeds``: each recipe is trained
   once per seed (the initial weights, the batches and the dropout masks,
   :attr:`jaxstyle.mason2022.train.LPNTrainConfig.seed`; default seed 0 alone), named
   ``<recipe> seed <n>`` for seeds other than 0. Trained models are kept in ``--run/<name>`` and
   reused on a re-run.
3. Runtime: every training style along ``straight`` and ``circle`` (10 s at its own speed, the
   path-following law of the quality benchmark), with the paper's runtime (``--phase-floor 0``)
   and with the local phases floored at :data:`jaxstyle.train.defaults.PHASE_FLOOR` of the style's
   capture rate (the default floor); both with the paper's joint blend on the feet unless
   ``--foot-smooth S`` (the commands' default is :data:`jaxstyle.train.defaults.FOOT_SMOOTH`),
   and on the other bones unless ``--body-smooth S`` (:data:`jaxstyle.train.defaults.BODY_SMOOTH`).
4. Measures (:func:`jaxstyle.output.quality.run`, the quality benchmark's): the local phases'
   advance over the capture's (``phase_rate_ratio``, stalled below
   :data:`jaxstyle.output.quality.STALL_RATIO`), steps per second after foot locking, raw foot
   skating of the network's joints, feet on the floor, style distance, each beside the capture;
   how much the pose moves (the standard deviation over time of the joints' positions in the
   root's frame, after the first second, in metres); how fast the feet move while the network
   itself says they are planted (``planted_speed_m_s``, :func:`planted_speed`: the horizontal
   speed of the ankles and toes while their foot's predicted contact label is on, after the first
   second; the capture's from its rows' velocities and contact labels) beside the root's speed;
   the feet's local-phase amplitude over the capture's (``foot_amplitude``,
   :func:`foot_amplitude_ratio`).

``--model DIR`` (repeatable) measures already trained models instead (e.g. the paper-size
``RUN/lpn`` of ``jaxstyle lpn``, reloaded with :func:`jaxstyle.mason2022.synthesis.load_model`, its
rows cached in ``--run/cache``), each named by its folder, with both runtimes: its training styles
and the new styles its FiLM generator was fine-tuned on (at their chosen rates, a failed check
included and marked). With ``--feedback`` it measures instead which fed-back input stills each
style's pose, fine-tuned ones included (:func:`feedback_rows`: along the style's two longest training clips, the
clips' joint features and local phases or the loop's own, with the runtime's ``--foot-smooth`` /
``--body-smooth``), written to ``--run/feedback.md`` and ``--run/feedback.csv``.

Writes ``--run/closed_loop.md`` (the per-row table and the summary per recipe and runtime) and
``--run/closed_loop.csv``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from jaxstyle.cli.args import add_joint_blend_args
from jaxstyle.control.lpn_phases import phase_amplitudes
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.folders import PAPER_BASE, available_styles
from jaxstyle.data.locate import mocap_dir
from jaxstyle.data.lpn_features import LPNLayout, bone_points, foot_bones
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2022 import pipeline, report
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.motion.character_frame import rotate_yaw
from jaxstyle.output import drive, quality
from jaxstyle.output import report as quality_report
from jaxstyle.train.defaults import PHASE_FLOOR

RECIPES = {"paper": {}, "noise": {"input_noise": 1.0}, "rollout": {"rollout_steps": 4},
           "contact1": {"contact_loss_weight": 1.0}, "contact10": {"contact_loss_weight": 10.0},
           "rollout_contact10": {"rollout_steps": 4, "contact_loss_weight": 10.0}}
PATHS = ("straight", "circle")
SECONDS = 10.0


def pose_motion_m(positions_TxJx3: np.ndarray, yaw_T: np.ndarray, origin_Tx2: np.ndarray, upm: float,
                  start: int) -> float:
    """Mean over joints of the standard deviation over frames ``start:`` of each joint's position
    in the root's ground frame (metres): 0 for a frozen pose whatever the root does."""
    p = positions_TxJx3[start:]
    rel_x, rel_z = p[..., 0] - origin_Tx2[start:, None, 0], p[..., 2] - origin_Tx2[start:, None, 1]
    c, s = np.cos(-yaw_T[start:])[:, None], np.sin(-yaw_T[start:])[:, None]
    local = np.stack([c * rel_x + s * rel_z, p[..., 1], -s * rel_x + c * rel_z], axis=-1)
    return float(local.std(axis=0).mean() / upm)


def _planted_steps(contacts_Tx2: np.ndarray, side, start: int) -> np.ndarray:
    """``(T - start - 1, F)``: the frame steps from ``start`` on where each foot joint's contact
    label (``side``: its foot, 0 left, 1 right) is on (``>= 0.5``) at both ends."""
    on = np.asarray(contacts_Tx2)[start:, list(side)] >= 0.5
    return on[1:] & on[:-1]


def planted_speed(positions_TxJx3: np.ndarray, contacts_Tx2: np.ndarray, skeleton, upm: float, start: int) -> float:
    """Mean horizontal speed (m/s) of the ankles and toes from frame ``start`` on over the frame
    steps where their foot's contact label (the network's own output, ``>= 0.5``) is on at both
    ends (:func:`jaxstyle.data.lpn_features.foot_bones`; NaN when never on)."""
    feet, side = foot_bones(skeleton)
    p = positions_TxJx3[start:, list(feet)][..., [0, 2]]
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1) * skeleton.fps / upm
    both = _planted_steps(contacts_Tx2, side, start)
    return float(speed[both].mean()) if both.any() else float("nan")


def stance_sweep(positions_TxJx3: np.ndarray, contacts_Tx2: np.ndarray, origin_Tx2: np.ndarray, yaw_T: np.ndarray,
                 skeleton, start: int) -> float:
    """How fast the planted feet sweep backwards under the body, over the root's speed: the mean,
    over the frame steps where their foot's contact label is on at both ends (from ``start``), of
    the ankles' and toes' velocity in the root's ground frame along the root's direction of
    travel (backwards positive), divided by the mean root speed over the same steps (the root's
    turn within a frame ignored). 1 for a foot that stays put while the root walks on; below 1,
    the leg sweeps too slowly for the root and the foot slides forwards. NaN when never on."""
    feet, side = foot_bones(skeleton)
    p, yaw = positions_TxJx3[start:, list(feet)], yaw_T[start:]
    o = np.stack([origin_Tx2[start:, 0], np.zeros(len(yaw)), origin_Tx2[start:, 1]], axis=-1)
    local = rotate_yaw(p - o[:, None], -yaw[:, None])[..., [0, 2]]  # in the root's ground frame
    step_local = np.diff(local, axis=0)  # (T-1, F, 2)
    root_local = rotate_yaw(np.diff(o, axis=0), -yaw[:-1])[:, [0, 2]]
    speed = np.linalg.norm(root_local, axis=-1)
    ahead = root_local / np.maximum(speed, 1e-9)[:, None]
    back = -np.sum(step_local * ahead[:, None], axis=-1)
    both = _planted_steps(contacts_Tx2, side, start)
    if not both.any():
        return float("nan")
    return float(back[both].mean() / np.broadcast_to(speed[:, None], both.shape)[both].mean())


def foot_amplitude_ratio(phases_Tx8: np.ndarray, dataset, name: str, start: int) -> float:
    """The median amplitude of the feet's local phases (limbs 2 and 3: right and left foot, each a
    ``(sin, cos)`` pair scaled by its amplitude) over frames ``start:`` over the median of style
    ``name``'s captured rows: below 1 the gating sees the feet's phases smaller than in the
    capture, and a limb whose amplitude falls to 0 no longer cycles the experts whatever its
    phase's advance (:func:`jaxstyle.control.lpn_phases.phase_amplitudes`)."""
    capture = float(np.median(phase_amplitudes(dataset.phases[style_rows(dataset, name)])[:, 2:]))
    return float(np.median(phase_amplitudes(phases_Tx8[start:])[:, 2:]) / capture) if capture > 0 else float("nan")


FEEDBACK_MODES = {"teacher-forced": (True, True), "own phases": (True, False), "own joints": (False, True),
                  "own joints and phases": (False, False)}


def feedback_rows(loaded: synthesis2022.Loaded, styles, new_styles=(), clips: int = 2, frames: int = 900
                  ) -> list[dict]:
    """Which fed-back input stills a style's pose: for each training style of ``styles`` and each
    fine-tuned new style of ``new_styles`` (its FiLM vector at its chosen rate, a failed check
    included and marked; its clips' rows), along each of the style's ``clips`` longest training
    clips (their first ``frames`` rows), the network reads the clip's trajectory and, per mode of
    :data:`FEEDBACK_MODES`, the clip's joint features and local phases or those its own loop
    carries (:func:`jaxstyle.control.lpn_controller.partly_forced`, with ``loaded``'s runtime).
    Per row, after the first second: ``feet_amplitude`` (median amplitude of the feet's carried
    local phases over the clip's) and ``ankle_motion`` (the ankles' standard deviation over time of
    their horizontal position in the character's frame over the clip's: near 0 for a still pose)."""

    from jaxstyle.control.lpn_controller import partly_forced

    model = loaded.character_model()
    ankles = list(foot_bones(loaded.data.skeleton)[0][:2])
    layout = LPNLayout(model.num_bones)
    characters = synthesis2022.characters(loaded, styles=list(styles), new_styles=list(new_styles),
                                          allow_failed=True)
    start = layout.input_groups["joint_position"].start

    def ankle_spread(joints_TxJ):
        pos = np.asarray(joints_TxJ)[60:, :3 * model.num_bones].reshape(-1, model.num_bones, 3)[:, ankles]
        return pos[..., [0, 2]].std(axis=0).mean()

    out = []
    for character in characters:
        ds = character.dataset
        own = ds.style == ds.styles.index(character.style)
        mine = np.unique(ds.clip[own & (ds.split == 0)] if (own & (ds.split == 0)).any() else ds.clip[own])
        for c in sorted(mine, key=lambda c: -np.sum(ds.clip == c))[:clips]:
            rows = np.where(ds.clip == c)[0]
            rows = rows[np.argsort(ds.frame[rows])][:frames]
            state = model.initial_state(ds, int(rows[0]), character.conditioning)
            capture_amp = np.median(phase_amplitudes(ds.phases[rows][60:])[:, 2:])
            capture_spread = ankle_spread(ds.inputs[rows][:, start:])
            for mode, flags in FEEDBACK_MODES.items():
                _, frame = partly_forced(model, character.conditioning, state, ds.inputs[rows], ds.phases[rows],
                                         np.asarray(flags))
                phases = np.asarray(frame.phases)
                joints = np.asarray(frame.outputs)[:, layout.output_groups["joint_position"]]
                out.append({"style": character.title, "clip": int(c), "frames": len(rows), "mode": mode,
                            "feet_amplitude": float(np.median(phase_amplitudes(phases[60:])[:, 2:]) / capture_amp),
                            "ankle_motion": float(ankle_spread(joints) / capture_spread)})
    return out


def capture_planted_speed(dataset, name: str, skeleton, upm: float) -> float:
    """:func:`planted_speed` of style ``name``'s capture: the ankles' and toes' horizontal
    velocities in its rows (:func:`jaxstyle.data.datasets.style_rows`) where the next frame's
    contact label of their foot is on."""
    feet, side = (list(a) for a in foot_bones(skeleton))
    y = dataset.outputs[style_rows(dataset, name)]
    groups = LPNLayout(len(bone_points(skeleton)[2])).output_groups
    v = y[:, groups["joint_velocity"]].reshape(len(y), -1, 3)[:, feet][..., [0, 2]]
    on = y[:, groups["foot_contact"]][:, side] >= 0.5
    return float(np.linalg.norm(v, axis=-1)[on].mean() * skeleton.fps / upm)


def teacher_forced(model: pipeline.Model) -> dict[str, float]:
    """``model`` teacher-forced on its test rows (dropout off, a FiLM model with each style's FiLM
    vector), one prediction per style: ``contact`` / ``contact_capture``, the mean over styles of
    :func:`jaxstyle.mason2022.loss.contact_loss` (metres per frame) of the prediction and of the
    captured next frame in its place; ``position_head`` / ``velocity_head`` / ``capture``, how far
    each head moves a planted foot: the mean over the ankles and toes of the rows whose captured
    next frame has their foot's contact label on (all styles' rows together) of the horizontal
    distance from the input position to the predicted one, of the predicted velocity, and of the
    captured velocity, in m/s (rows at 60 fps)."""
    from jaxstyle.mason2022.loss import _group, contact_loss, positions_m
    from jaxstyle.mason2022.train import film_vectors
    from jaxstyle.nn import style_models

    data, config, params, c = model.data, model.config, model.params, model.data.bones.contact
    vectors = film_vectors(params, data) if config.modulation == "film" else None
    feet, side, n = list(c.feet), list(c.side), len(c.x_position[1]) // 3
    contact, capture, sums, count = [], [], np.zeros(3), 0

    def ground(v_BxD):  # the feet's horizontal (x, z) of flat (B, 3 J) joint vectors
        return np.asarray(v_BxD).reshape(len(v_BxD), n, 3)[:, feet][..., [0, 2]]

    for s, rows in enumerate(data.test_rows):
        x, y = data.x[rows], data.y[rows]
        style = vectors[s] if vectors is not None else style_models.style_runtime(params, config, s)
        pred = style_models.model_apply(params, config, x, data.gate[rows], style)
        contact.append(float(contact_loss(x, pred, y, data.bones)))
        capture.append(float(contact_loss(x, y, y, data.bones)))
        moved = ground(positions_m(pred, data.bones)) - ground(_group(x, c.x_position))
        on = np.asarray(_group(y, c.y_contact))[:, side] >= 0.5
        sums += [np.linalg.norm(a, axis=-1)[on].sum()
                 for a in (moved, ground(_group(pred, c.y_velocity)), ground(_group(y, c.y_velocity)))]
        count += on.sum()
    pos, vel, cap = sums / max(count, 1) * 60.0
    return {"contact": float(np.mean(contact)), "contact_capture": float(np.mean(capture)),
            "position_head": float(pos), "velocity_head": float(vel), "capture": float(cap)}


def model_line(model: pipeline.Model) -> str:
    """The test MSE and the teacher-forced figures of :func:`teacher_forced`."""
    t = teacher_forced(model)
    return (f"test MSE {np.mean(pipeline.model_losses(model)['mse']):.4f}, test contact loss {t['contact']:.4f} "
            f"m/frame (capture {t['contact_capture']:.4f}), planted feet teacher-forced: position head "
            f"{t['position_head']:.2f} m/s, velocity head {t['velocity_head']:.2f} m/s (capture {t['capture']:.2f})")


def runtime_name(floor: float) -> str:
    return "paper (no floor)" if floor == 0 else f"phase floor {floor:g}"


def measure(loaded: synthesis2022.Loaded, styles, recipe: str, new_styles=(), blend_bias: float = 1.5) -> list[dict]:
    """The quality benchmark's rows (:func:`jaxstyle.output.quality.measure_rollouts`, the captures'
    included) of every style along :data:`PATHS`, each with its ``recipe``, ``phase_floor`` and
    ``pose_motion_m``, driven with the trajectory blend's ``blend_bias``, and named ``model`` =
    ``"<recipe>, <runtime>"`` (one group of :func:`jaxstyle.mason2022.report.closed_loop_figures`)."""
    skeleton = loaded.data.skeleton
    upm = estimate_units_per_meter(skeleton)
    chars = synthesis2022.characters(loaded, styles=styles, new_styles=new_styles, allow_failed=True)
    driven = drive.drive(loaded.character_model(blend_bias=blend_bias), chars, drive.Course(PATHS, SECONDS),
                         units_per_meter=upm, fps=skeleton.fps)
    subjects = [quality.subject(c, "base", loaded.model.name) for c in chars]
    rows = quality.measure_rollouts(subjects, driven.pairs, driven.signals, driven.rollouts, skeleton,
                                    driven.speeds).rows
    out = jax.tree.map(np.asarray, driven.rollouts)
    start = int(skeleton.fps)
    for k, (i, p) in enumerate(driven.pairs):
        r = next(r for r in rows if r["style"] == chars[i].title and r["path"] == p)
        positions = out.positions[k][:, :skeleton.num_joints]
        r["pose_motion_m"] = pose_motion_m(positions, out.yaw[k], out.origin[k], upm, start)
        r["planted_speed_m_s"] = planted_speed(positions, out.contacts[k], skeleton, upm, start)
        r["root_speed_m_s"] = float(np.linalg.norm(np.diff(out.origin[k][start:], axis=0), axis=-1).mean()
                                    * skeleton.fps / upm)
        r["stance_sweep"] = stance_sweep(positions, out.contacts[k], out.origin[k], out.yaw[k], skeleton, start)
        r["foot_amplitude"] = foot_amplitude_ratio(out.phases[k], chars[i].dataset, chars[i].style, start)
    for c, speed in zip(chars, driven.speeds, strict=True):
        r = next(r for r in rows if r["style"] == c.title and r["path"] == "capture")
        r["planted_speed_m_s"] = capture_planted_speed(c.dataset, c.style, skeleton, upm)
        r["root_speed_m_s"] = float(speed)
    group = {"model": f"{recipe}, {runtime_name(loaded.phase_floor)}", "recipe": recipe,
             "phase_floor": loaded.phase_floor}
    return [{**r, **group} for r in rows]


def summary(rows: list[dict]) -> list[str]:
    """One line per (recipe, runtime) from :func:`jaxstyle.mason2022.report.closed_loop_figures`,
    with the medians of the planted feet's and the root's speeds (:func:`planted_speed`) of the
    generated rows and of their captures, and of the generated rows' :func:`stance_sweep`."""
    lines = ["| recipe | runtime | rows stalled | rows not stepping | median phase rate / capture | rows stepping "
             "within 25% of capture | median steps/s / capture | median raw skating / capture | median style "
             "distance m | median planted-foot / root speed m/s (capture) | median stance sweep / root speed |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = {r["model"]: r for r in rows}

    def med(mine, key):
        return float(np.nanmedian([r.get(key, np.nan) for r in mine])) if mine else np.nan

    for model, f in report.closed_loop_figures(rows).items():
        n = f["rows"] - f["diverged"]
        gen = [r for r in rows if r["model"] == model and r["path"] != "capture"]
        cap = [r for r in rows if r["model"] == model and r["path"] == "capture"]
        lines.append(f"| {groups[model]['recipe']} | {runtime_name(groups[model]['phase_floor'])} | "
                     f"{f['stalled']} / {n} | {f['not_stepping']} / {n} | {f['phase_rate_ratio']:.2f} | "
                     f"{f['stepping']} / {n} | "
                     f"{f['steps_ratio']:.2f} | {f['skating_ratio']:.1f} | {f['style_distance']:.2f} | "
                     f"{med(gen, 'planted_speed_m_s'):.2f} / {med(gen, 'root_speed_m_s'):.2f} "
                     f"({med(cap, 'planted_speed_m_s'):.2f} / {med(cap, 'root_speed_m_s'):.2f}) | "
                     f"{med(gen, 'stance_sweep'):.2f} |")
    return lines


def row_table(rows: list[dict]) -> list[str]:
    lines = ["| recipe | runtime | style | path | phase rate / capture | pose motion m | steps/s (capture) | "
             "raw skating m/s (capture) | feet on floor (capture) | style distance m | planted-foot / root speed m/s "
             "(capture) | stance sweep / root speed | feet's phase amplitude / capture |", "|---|" * 1 + "---|" * 12]
    captures = {(r["model"], r["style"]): r for r in rows if r["path"] == "capture"}
    for r in rows:
        if r["path"] == "capture":
            continue
        cap = captures[(r["model"], r["style"])]
        runtime = "paper" if r["phase_floor"] == 0 else f"floor {r['phase_floor']:g}"
        stalled = " stalled" if r["phases_stalled"] else ""
        lines.append(f"| {r['recipe']} | {runtime} | {r['style']} | {r['path']} | "
                     f"{r['phase_rate_ratio']:.2f}{stalled} | "
                     f"{r['pose_motion_m']:.3f} | {r['steps_per_s']:.2f} ({cap['steps_per_s']:.2f}) | "
                     f"{r['foot_skating_m_s']:.2f} ({cap['foot_skating_m_s']:.2f}) | {r['contact_fraction']:.2f} "
                     f"({cap['contact_fraction']:.2f}) | {r['style_distance']:.2f} | "
                     f"{r['planted_speed_m_s']:.2f} / {r['root_speed_m_s']:.2f} "
                     f"({cap['planted_speed_m_s']:.2f} / {cap['root_speed_m_s']:.2f}) | {r['stance_sweep']:.2f} | "
                     f"{r['foot_amplitude']:.2f} |")
    return lines


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=None, help="the 100STYLE folder (default $JAXSTYLE_MOCAP/100style)")
    p.add_argument("--run", type=Path, default=Path("runs/closed_loop"))
    p.add_argument("--epochs", type=int, default=4)
    p.add_argument("--recipes", nargs="+", choices=list(RECIPES), default=list(RECIPES))
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="train each recipe once per seed")
    p.add_argument("--model", type=Path, action="append", help="measure this trained model's folder instead")
    p.add_argument("--blend-bias", type=float, default=1.5,
                   help="the runtime's trajectory blend bias (default 1.5, the synthesis default)")
    add_joint_blend_args(p, paper=True)
    p.add_argument("--amplitude-floor", type=float, default=0.0,
                   help="each limb's local-phase amplitude kept at least this fraction of its style's captured "
                        "median (default 0: the paper's runtime; StyleNetModel.create)")
    p.add_argument("--feedback", action="store_true",
                   help="with --model: which fed-back input stills each style's pose (feedback_rows) instead of "
                        "driving the paths")
    args = p.parse_args(argv)
    if args.feedback:
        if not args.model:
            p.error("--feedback measures the models of --model")
        return write_feedback(args)
    if args.model:
        t0 = time.perf_counter()
        rows = []
        for folder in args.model:
            loaded = synthesis2022.load_model(folder, cache=args.run / "cache")
            print(f"{folder}: {loaded.model.name}, {loaded.epoch_text()}, {model_line(loaded.model)}")
            chosen = Path(folder) / "chosen_rates.json"
            new = list(json.loads(chosen.read_text())) if chosen.is_file() and loaded.data.new is not None else []
            for floor in (0.0, PHASE_FLOOR):
                rows += measure(loaded._replace(phase_floor=floor, foot_smooth=args.foot_smooth,
                                                amplitude_floor=args.amplitude_floor, body_smooth=args.body_smooth),
                                list(loaded.model.data.styles), str(folder), new, args.blend_bias)
        title = f"the models of {', '.join(map(str, args.model))} ({time.perf_counter() - t0:.0f} s)"
        return write_report(args, rows, title)
    root = args.data or mocap_dir() / "100style"
    styles = [s for s in PAPER_BASE if s in available_styles(root)]
    t0 = time.perf_counter()
    data = pipeline.build_data(root, styles, cache=args.run / "cache")
    config = pipeline.model_config(data.base, hidden=256, generator_hidden=512, filters=32)
    rows = []
    for recipe in args.recipes:
        for seed in args.seeds:
            name = recipe if seed == 0 else f"{recipe} seed {seed}"
            folder = args.run / name.replace(" ", "_")
            t1 = time.perf_counter()
            model = pipeline.train_model(data, config, folder, epochs=args.epochs, progress=False,
                                         learning_rate=1e-3, seed=seed, **RECIPES[recipe])
            trained = time.perf_counter() - t1
            print(f"{name}: {args.epochs} epochs, {trained:.0f} s (this call), {model_line(model)}", flush=True)
            for floor in (0.0, PHASE_FLOOR):
                loaded = synthesis2022.Loaded(model, data, folder, args.epochs, phase_floor=floor,
                                              foot_smooth=args.foot_smooth, amplitude_floor=args.amplitude_floor,
                                              body_smooth=args.body_smooth)
                rows += measure(loaded, styles, name, blend_bias=args.blend_bias)
    write_report(args, rows, f"{len(styles)} styles x {len(PATHS)} paths, {SECONDS:g} s each; LPN-FiLM 256 hidden, "
                 f"{args.epochs} epochs at 1e-3 ({time.perf_counter() - t0:.0f} s in all)")


def feedback_table(rows: list[dict]) -> list[str]:
    """Per model and style, each mode's feet amplitude and ankle motion over the capture's
    (:func:`feedback_rows`; the clips' values separated by ``/``)."""
    lines = ["| model | style | " + " | ".join(f"{m}: feet amplitude, ankle motion" for m in FEEDBACK_MODES) + " |",
             "|---|---|" + "---|" * len(FEEDBACK_MODES)]
    for model in dict.fromkeys(r["model"] for r in rows):
        for style in dict.fromkeys(r["style"] for r in rows if r["model"] == model):
            mine = [r for r in rows if (r["model"], r["style"]) == (model, style)]
            cells = []
            for mode in FEEDBACK_MODES:
                got = [r for r in mine if r["mode"] == mode]
                cells.append(" / ".join(f"{r['feet_amplitude']:.2f}" for r in got) + ", "
                             + " / ".join(f"{r['ankle_motion']:.2f}" for r in got))
            lines.append(f"| {model} | {style} | " + " | ".join(cells) + " |")
    return lines


def write_feedback(args) -> None:
    t0 = time.perf_counter()
    rows = []
    for folder in args.model:
        loaded = synthesis2022.load_model(folder, cache=args.run / "cache")._replace(
            foot_smooth=args.foot_smooth, body_smooth=args.body_smooth, amplitude_floor=args.amplitude_floor)
        chosen = Path(folder) / "chosen_rates.json"
        new = list(json.loads(chosen.read_text())) if chosen.is_file() and loaded.data.new is not None else []
        rows += [{"model": str(folder), **r} for r in feedback_rows(loaded, loaded.model.data.styles, new)]
    lines = [f"which fed-back input stills the pose: the models of {', '.join(map(str, args.model))}, each style's "
             f"two longest training clips, fine-tuned styles included ({time.perf_counter() - t0:.0f} s)", "",
             *feedback_table(rows)]
    args.run.mkdir(parents=True, exist_ok=True)
    (args.run / "feedback.md").write_text("\n".join(lines) + "\n")
    quality_report.write_csv(rows, args.run / "feedback.csv")
    print("\n".join(lines))
    print(f"written: {args.run / 'feedback.md'}, {args.run / 'feedback.csv'}")


def write_report(args, rows: list[dict], title: str) -> None:
    head = [title, "", *summary(rows)]
    lines = [*head, "", *row_table(rows)]
    args.run.mkdir(parents=True, exist_ok=True)
    (args.run / "closed_loop.md").write_text("\n".join(lines) + "\n")
    quality_report.write_csv(rows, args.run / "closed_loop.csv")
    print("\n".join(head))
    print(f"written: {args.run / 'closed_loop.md'}, {args.run / 'closed_loop.csv'}")


if __name__ == "__main__":
    main()
