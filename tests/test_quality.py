"""The quality benchmark on the 2022 controller (:func:`jaxstyle.output.quality.run` with a
:class:`jaxstyle.control.lpn_controller.StyleNetModel`) and the
demo's quality table: a tiny LPN-FiLM trained in a fixture on two
procedural styles is measured along the protocol's paths, and every figure is recomputed
independently from what ``jaxstyle synthesize --model lpn-film`` writes for the same characters
(the ``.npz`` of the network's joints, the BVH file of the exported skeleton) with the
:mod:`jaxstyle.output.metrics` functions the 2018 path uses."""

from __future__ import annotations

import argparse
import csv

import jax
import numpy as np
import pytest

import jaxstyle as js
from jaxstyle.cli import demo
from jaxstyle.control import paths
from jaxstyle.data import datasets, folders, procedural
from jaxstyle.data.lpn_features import decode_lpn
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2022 import pipeline, styledata
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.nn import style_models
from jaxstyle.output import footlock, metrics, quality, report, synthesis
from jaxstyle.output import style as style_lib
from jaxstyle.output.synthesis import EXPORTED_FIGURES

SECONDS = 3.5  # stop_and_go: 2 s walk, then the stop command; 1.5 s to stop
SECONDS_DATA = 8  # shorter clips hold no style clip (240 frames) in their training rows


@pytest.fixture(scope="module")
def loaded(tmp_path_factory):
    """A tiny LPN-FiLM on two procedural styles, untrained (what is tested is the measuring, not
    the motion; reloading a trained model is test_synthesis_lpn.py's)."""
    root = procedural.write_dataset(tmp_path_factory.mktemp("data") / "procedural", styles=["Neutral", "Crouched"],
                                    gaits=("FW",), seconds=SECONDS_DATA, progress=False)
    run = tmp_path_factory.mktemp("run")
    styles, new_styles = folders.split_styles(root, [])
    data = pipeline.build_data(root, styles, new_styles, cache=run / "cache")
    config = pipeline.model_config(data.base, hidden=8, generator_hidden=16, filters=4)
    style_data = styledata.style_data(data.base, data.skeleton, backbone=config.backbone)
    # random weights in the model's tree (jax.eval_shape: no per-shape initialiser compiles)
    rng = np.random.default_rng(0)
    params = jax.tree.map(lambda v: (0.1 * rng.standard_normal(v.shape)).astype(v.dtype),
                          jax.eval_shape(lambda key: style_models.init_model(key, config), jax.random.PRNGKey(0)))
    return synthesis2022.Loaded(pipeline.Model(pipeline.MODEL, config, params, style_data), data, run / "lpn", 0)


def test_lpn_characters_are_measured_like_the_2018_ones(loaded, tmp_path):
    model, skeleton = loaded.model, loaded.data.skeleton
    chars = synthesis2022.characters(loaded, styles=["Neutral", "Crouched"])  # the demo test's shapes: one compile
    subjects = [quality.subject(c, "base", model.name) for c in chars]
    names = quality.TARGET_PATHS
    rows, drawn = quality.run(loaded.character_model(), subjects, skeleton, path_names=names, seconds=SECONDS)
    assert [(r["model"], r["style"], r["path"]) for r in rows] == [
        ("LPN FiLM", s, p) for s in ("Neutral", "Crouched") for p in names] + [
        ("LPN FiLM", s, "capture") for s in ("Neutral", "Crouched")]
    # the same characters through `jaxstyle synthesize --model lpn-film`'s library path, written to files
    synth = synthesis.synthesize(loaded.character_model(), chars, skeleton, tmp_path,
                                 synthesis.SynthesisOptions(path_names=names, seconds=SECONDS, gif=False))
    upm, fps, J = estimate_units_per_meter(skeleton), skeleton.fps, skeleton.num_joints
    for row in rows[:-2]:
        p, style = row["path"], row["style"]
        assert row["finite"] and row["speed_m_s"] == pytest.approx(synth.speeds[style])
        sig = paths.named(p, SECONDS, synth.speeds[style], units_per_meter=upm, fps=fps)
        with np.load(tmp_path / "bvh" / f"{style}_{p}.npz") as z:
            net, origin, yaw, outputs = (z[k].astype(np.float64) for k in ("positions", "origin", "yaw", "outputs"))
        assert net.shape[1] > J  # the LPN's hand end sites, which the metrics leave out
        net = net[:, :J]
        # the BVH file holds the locked feet (the default); the skeleton before locking is the
        # decoded outputs'
        fixed = js.global_positions(js.read_bvh(tmp_path / "bvh" / f"{style}_{p}.bvh"))
        bvh_pos = js.global_positions(decode_lpn(outputs, skeleton))
        np.testing.assert_allclose(drawn[(style, p)][0], fixed, rtol=1e-5, atol=1e-3)  # previews draw the BVH's
        steps = metrics.step_figures(fixed, skeleton, fps)
        err = np.linalg.norm(origin - sig.positions, axis=-1) / upm
        length = np.sum(np.linalg.norm(sig.velocity, axis=1)) / fps / upm
        stops = metrics.stop_times(origin, sig.velocity, fps, units_per_meter=upm)

        def skate(pos):
            return metrics.foot_skating(pos, skeleton, fps, units_per_meter=upm)

        want = {"foot_skating_m_s": skate(net), "foot_skating_bvh_m_s": skate(bvh_pos),
                "foot_skating_locked_m_s": skate(fixed), "steps_per_s": steps.steps_per_s,
                "stance_fraction": steps.stance_fraction, "slide_per_contact_m": steps.slide_per_contact_m,
                "lifted_steps_per_s": steps.lifted_steps_per_s,
                "steps_per_s_bvh": metrics.step_figures(bvh_pos, skeleton, fps).steps_per_s,
                "ik_foot_offset_max_m": metrics.foot_offset_max_m(bvh_pos, fixed, skeleton, units_per_meter=upm),
                "foot_below_floor_m": metrics.foot_below_floor_m(fixed, skeleton, footlock.skeleton_floor(skeleton),
                                                                 units_per_meter=upm),
                "contact_fraction": metrics.motion_quality(net, skeleton, fps, units_per_meter=upm).contact_fraction,
                "bone_error_max": metrics.bone_length_errors(net, skeleton).max(),
                "bone_error_bvh_max": metrics.bone_length_errors(bvh_pos, skeleton).max(),
                "joint_difference_max_m": metrics.max_joint_difference_m(net, bvh_pos, units_per_meter=upm),
                "path_error_mean_m": err.mean(), "path_error_final_m": err[-1],
                "path_error_final_pct": 100 * err[-1] / length,
                "heading_error_deg": metrics.heading_error_deg(yaw, sig.yaw),
                "stop_time_s": np.max(stops) if len(stops) else np.nan,
                "jitter_m_s3": metrics.jitter(net, fps, units_per_meter=upm),
                "ankle_jerk_locked_m_s3": metrics.foot_jerk(fixed, skeleton, fps, units_per_meter=upm)}
        for k, v in want.items():  # the BVH file holds 6 decimals
            np.testing.assert_allclose(row[k], v, rtol=2e-3, atol=2e-4, equal_nan=True, err_msg=f"{p}: {k}")
        assert row["bone_error_bvh_max"] < 1e-5 < row["bone_error_max"]
        # the style figures: of the BVH's skeleton against the style's capture, by the style module
        cap = datasets.load_clip(quality.capture_spec(loaded.data.base, style), fps=60.0)
        shown = style_lib.style_stats(fixed, skeleton, fps)
        captured = style_lib.style_stats(js.global_positions(cap), cap, cap.fps)
        for k, v in style_lib.style_distance(shown, captured).items():
            np.testing.assert_allclose(row[k], v, rtol=2e-3, atol=2e-4, equal_nan=True, err_msg=f"{p}: {k}")
        np.testing.assert_allclose(row["wrist_range_ratio"], shown.wrist_range_m / captured.wrist_range_m, rtol=2e-3)
        # lifted steps per second of the frames the path moves, over the capture's
        moving_s = np.count_nonzero(np.linalg.norm(sig.velocity, axis=1) > 1e-6) / fps
        cap_lifted = metrics.step_figures(js.global_positions(cap), cap, cap.fps).lifted_steps_per_s
        np.testing.assert_allclose(row["lifted_step_ratio"],
                                   steps.lifted_steps_per_s * len(fixed) / fps / moving_s / cap_lifted, rtol=2e-3)
        assert row["not_stepping"] == bool(row["lifted_step_ratio"] < quality.STEP_RATIO)
        # `jaxstyle synthesize` reports the exported skeleton's figures too, by the same function
        srow = next(r for r in synth.rows if (r["style"], r["path"]) == (style, p))
        for k in (*EXPORTED_FIGURES, "lifted_step_ratio"):
            np.testing.assert_allclose(srow[k], row[k], rtol=1e-6, equal_nan=True, err_msg=k)
        assert srow["not_stepping"] == row["not_stepping"]
        if p == "stop_and_go":
            assert len(stops) == 1  # its stop command at 2 s
    # the capture row: the style's first walking clip, by forward kinematics
    cap = rows[-2]
    base = loaded.data.base
    spec = base.specs[int(base.clip[base.rows_of_style("Neutral", "train")[0]])]  # the data holds FW clips only
    clip = datasets.load_clip(spec, fps=fps)
    np.testing.assert_allclose(cap["foot_skating_m_s"], metrics.reference_quality(clip).foot_skating_m_s, rtol=1e-9)
    assert np.isnan(cap["path_error_final_m"]) and cap["kind"] == "base"
    # reported with a model column; the skating targets against that model's capture row
    assert report.table(rows)[2].startswith("| LPN FiLM | Crouched | capture (Crouched_FW.bvh) | ")  # by model, style
    checks = report.targets(rows)
    skating = [c for c in checks if c["target"].startswith("raw skating")]
    assert [c["model"] for c in skating] == ["LPN FiLM"] * 8
    np.testing.assert_allclose(skating[0]["limit"], 1.5 * cap["foot_skating_m_s"])


def test_a_pose_frozen_while_its_root_walks_is_marked_not_stepping(tmp_path):
    """The lifted-step figure on a real step count: a procedural walk against its own capture reads
    1 on a path that always moves and on one that stands a third of the time with no step there;
    the same clip's first pose carried along by the root (frozen legs, phases irrelevant) reads 0
    and is marked in the table; no figure without lifted steps or without motion."""
    root = procedural.write_dataset(tmp_path / "data", styles=["Neutral"], gaits=("FW",), seconds=6, progress=False)
    clip = js.read_bvh(root / "Neutral" / "Neutral_FW.bvh")
    pos, fps = js.global_positions(clip), clip.fps
    walk = metrics.step_figures(pos, clip, fps).lifted_steps_per_s
    assert walk > 1.0  # the generated walk lifts its feet: the reference is a real count
    T = len(pos)
    moving = paths.straight(T / fps, 1.0, fps=fps)
    f = quality.stepping_figures({"lifted_steps_per_s": walk}, moving, walk)
    assert f["lifted_step_ratio"] == pytest.approx(1.0) and f["not_stepping"] is False
    # standing a third of the frames: the same steps over two thirds of the time read the same rate
    go = paths.stop_and_go(T / fps, 1.0, fps=fps, go=2.0, stop=1.0)
    share = np.count_nonzero(np.linalg.norm(go.velocity, axis=1) > 0) / T
    f = quality.stepping_figures({"lifted_steps_per_s": walk * share}, go, walk)
    assert f["lifted_step_ratio"] == pytest.approx(1.0) and f["not_stepping"] is False
    # the first pose carried along the root's horizontal path: the legs never leave the floor
    frozen = pos[:1] + (pos[:, :1] - pos[:1, :1]) * np.array([1.0, 0.0, 1.0])
    lifted = metrics.step_figures(frozen, clip, fps).lifted_steps_per_s
    row = {"model": "LPN FiLM", "style": "Neutral", "path": "straight", "lifted_steps_per_s": lifted,
           **quality.stepping_figures({"lifted_steps_per_s": lifted}, moving, walk)}
    assert lifted == 0.0 and row["lifted_step_ratio"] == 0.0 and row["not_stepping"] is True
    assert report.stalled_mark(row) == f" {quality.NOT_STEPPING_MARK}"
    assert report.stalled_mark({**row, "not_stepping": "True", "phases_stalled": "True"}) == (
        f" {quality.STALLED_MARK} {quality.NOT_STEPPING_MARK}")  # CSV rows: strings
    assert quality.NOT_STEPPING_MARK in synthesis.quality_table([{**row, "bone_error_mean": 0.0,
                                                                  "bone_error_max": 0.0}])[2]
    standing = paths.from_velocity(np.zeros((T, 2)), fps)
    for r, sig, ref in (({"lifted_steps_per_s": np.nan}, moving, walk), ({"lifted_steps_per_s": 1.0}, standing, walk),
                        ({"lifted_steps_per_s": 1.0}, moving, 0.0)):
        f = quality.stepping_figures(r, sig, ref)
        assert np.isnan(f["lifted_step_ratio"]) and f["not_stepping"] is None
    assert report.stalled_mark({"not_stepping": None}) == ""


def test_demo_prints_the_benchmark_table_with_target_marks(loaded, tmp_path):
    said = []

    class Run:
        def say(self, text=""):
            said.append(text)

    args = argparse.Namespace(synth_seconds=SECONDS)
    out = demo.report_quality(Run(), args, lambda names, seconds: demo.lpn_quality(loaded, ["Neutral", "Crouched"], [],
                                                                                    names, seconds),
                              tmp_path / "quality_targets.csv")
    with open(out, newline="") as f:
        rows = list(csv.DictReader(f))
    assert {(r["style"], r["path"]) for r in rows} == {(s, p) for s in ("Neutral", "Crouched")
                                                       for p in (*quality.TARGET_PATHS, "capture")}
    text = "\n".join(said)
    assert report.table([])[0] in said and "| LPN FiLM | Neutral | straight" in text
    marks = [line for line in said if line.startswith("| LPN FiLM |") and line.endswith(("| pass |", "| FAIL |"))]
    lock_marks = [line for line in marks if any(f"| {t} |" in line for t in report.LOCK_TARGETS)]
    assert len(lock_marks) == 2 * 4 * len(report.LOCK_TARGETS)  # every row, every foot-locking target
    for r in rows:  # the foot offset marks agree with the CSV
        if r["path"] != "capture":
            mark = "pass" if float(r["ik_foot_offset_max_m"]) <= 0.15 else "FAIL"
            assert any(line.startswith(f"| LPN FiLM | {r['style']} | {r['path']} | foot offset <= 0.15 m |")
                       and line.endswith(f"| {mark} |") for line in lock_marks)
    marks = [line for line in marks if line not in lock_marks]
    assert len(marks) == 2 * 4  # 2 styles x (3 path-error targets + 1 stop)
    for r in rows:  # each mark agrees with the CSV's figure and the targets' limits
        if r["path"] in quality.FOLLOW_PATHS:
            value, limit = float(r["path_error_final_m"]), 0.3
        elif r["path"] == "stop_and_go":
            value, limit = float(r["stop_time_s"]), 0.5
        else:
            continue
        mark = "pass" if value <= limit else "FAIL"
        assert any(line.startswith(f"| LPN FiLM | {r['style']} | {r['path']} |") and line.endswith(f"| {mark} |")
                   for line in marks), (r["style"], r["path"], value)
    met = sum(line.endswith("| pass |") for line in marks)
    assert f"{met} of 8 met" in said[-1]
