"""The closed-loop check of fine-tuned new styles and the rate choice, both papers' (the 2018
adapters' few-shot sweep, :func:`jaxstyle.mason2018.selection.check_rollouts`; the 2022 FiLM
generators' sweep, :func:`jaxstyle.mason2022.finetune.closed_loop_check`).

Each paper measures its new styles' captures and the characters' starts from its own data
(:class:`StyleStart`); the rest is written once here, for any
:class:`jaxstyle.control.model.CharacterModel`: driving every fine-tuned pair (style x dropout
rate) and the model before fine-tuning along the check's path in one batched rollout
(:func:`check_pairs`, :class:`jaxstyle.train.defaults.RolloutCheck`), the judgement of those
rollouts (:func:`judge_pairs`: what is measured of each, :func:`rollout_measures`; when a pair
passes, :func:`passes_check`, against the model before fine-tuning) and which rate is chosen
(:func:`choose_rates`).
"""

from __future__ import annotations

from typing import Any, NamedTuple, Sequence

import numpy as np

from jaxstyle.control import loop
from jaxstyle.control.model import CharacterModel, rollout_batch
from jaxstyle.motion import Motion
from jaxstyle.output import metrics
from jaxstyle.train.defaults import RolloutCheck

NAN_MEASURES = {"finite": 0.0, "bone_error": np.nan, "contact_fraction": np.nan, "skating_m_s": np.nan,
                "progress": np.nan}


class Judging(NamedTuple):
    """What rollouts are judged with: the ``skeleton`` (a clip of it: bone lengths, feet), the frame
    rate ``fps``, ``units_per_meter`` and the ``check``'s thresholds."""

    skeleton: Motion
    fps: float
    units_per_meter: float
    check: RolloutCheck


class Captures(NamedTuple):
    """Per new style, of its capture: ``floors`` (its feet's planted heights), ``speeds_S`` (its
    median speed, file units per second) and ``contact_fraction_S`` (the share of frames with a
    foot on the floor)."""

    floors: Sequence[Any]
    speeds_S: np.ndarray
    contact_fraction_S: np.ndarray


def rollout_measures(positions_TxJx3, origin_Tx2, finite: bool, judging: Judging, floor,
                     speed: float) -> dict[str, float]:
    """One rollout's measures (:data:`jaxstyle.train.defaults.ROLLOUT_FIELDS` but ``passed``), NaN
    when not ``finite``: mean bone-length error, the share of frames with a foot on the floor and
    the foot skating (:func:`jaxstyle.output.metrics.positions_foot_stats`, over the style's
    ``floor`` heights), and the distance travelled over the path's length (``speed`` in file units
    per second times :attr:`RolloutCheck.seconds`)."""
    if not finite:
        return dict(NAN_MEASURES)
    skeleton, fps, units_per_meter, check = judging
    feet = metrics.positions_foot_stats(positions_TxJx3, skeleton, fps, floor, units_per_meter=units_per_meter,
                                        tolerance_m=check.tolerance_m)
    travelled = float(np.sum(np.linalg.norm(np.diff(origin_Tx2, axis=0), axis=-1)))
    return {"finite": 1.0, "bone_error": float(np.mean(metrics.bone_length_errors(positions_TxJx3, skeleton))),
            "contact_fraction": feet.contact_fraction, "skating_m_s": feet.skating,
            "progress": travelled / (speed * check.seconds) if speed > 0 else np.nan}


def judge_pairs(positions, origins, finite_SxR1: np.ndarray, judging: Judging, captures: Captures
                ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Both papers' closed-loop check of a sweep, from its rollouts: ``positions[s][r]`` ``(T, J,
    3)`` and ``origins[s][r]`` ``(T, 2)`` of every (new style ``s``, rate ``r``) pair and, as the
    last ``r``, of the model before fine-tuning from the same start on the same path;
    ``finite_SxR1`` whether each rollout stayed finite; ``judging`` (:class:`Judging`); per style
    its capture's figures (:class:`Captures`). Returns the pairs' ``(S, R)`` measures
    (:func:`rollout_measures`) with ``passed`` (:func:`passes_check`), and per style the model
    before fine-tuning's ``base_skating_m_s`` and ``base_bone_error``."""
    num_styles, num_cols = np.shape(finite_SxR1)
    measures = {k: np.full((num_styles, num_cols), np.nan) for k in NAN_MEASURES}
    for s in range(num_styles):
        for r in range(num_cols):
            row = rollout_measures(positions[s][r], origins[s][r], bool(finite_SxR1[s, r]), judging,
                                   captures.floors[s], float(captures.speeds_S[s]))
            for k, v in row.items():
                measures[k][s, r] = v
    base = {"base_skating_m_s": measures["skating_m_s"][:, -1], "base_bone_error": measures["bone_error"][:, -1]}
    out = {k: v[:, :-1] for k, v in measures.items()}
    out["passed"] = passes_check(out, captures.contact_fraction_S, base["base_skating_m_s"],
                                 np.asarray(captures.speeds_S) / judging.units_per_meter, judging.check).astype(float)
    return out, base


class StyleStart(NamedTuple):
    """One new style's check, as its paper's data give it: the characters' start ``state``
    (:meth:`jaxstyle.control.model.CharacterModel.initial_state` at a real frame of the style), its
    capture's median ground ``speed`` (file units per second: the check's path is walked at it), its
    feet's planted ``floor`` heights and its ``contact_fraction`` (the share of frames with a foot
    on the floor)."""

    state: Any
    speed: float
    floor: Any
    contact_fraction: float


def check_pairs(character: CharacterModel, styles_SxR1: Sequence[Sequence[Any]], starts: Sequence[StyleStart],
                judging: Judging) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Both papers' closed-loop check of a fine-tuning sweep: every new style ``s`` drives its
    ``R + 1`` conditionings ``styles_SxR1[s]`` (its ``R`` fine-tuned ones, then the model before
    fine-tuning's) from ``starts[s].state`` along :func:`jaxstyle.control.loop.turning_path` at
    ``starts[s].speed``, turning ``judging.check.turn_deg_per_s`` for ``judging.check.seconds``,
    all ``S (R + 1)`` characters in ONE batched rollout
    (:func:`jaxstyle.control.model.rollout_batch`, the model's weights shared); then
    :func:`judge_pairs` (the skeleton's joints of the network's positions; a rollout is finite when
    its positions and outputs are). Returns :func:`judge_pairs`' ``(S, R)`` measures and the model
    before fine-tuning's per-style figures."""
    fps, check = float(judging.fps), judging.check
    frames = int(round(check.seconds * fps))
    num_cols = {len(row) for row in styles_SxR1}
    if len(num_cols) != 1 or len(styles_SxR1) != len(starts):
        raise ValueError(f"styles_SxR1 must have one row of the same length per start, got rows of lengths "
                         f"{sorted(num_cols)} for {len(starts)} starts")
    grid = (len(starts), num_cols.pop())
    states, controls = [], []
    for start in starts:
        control = loop.turning_path(frames, start.speed, np.deg2rad(check.turn_deg_per_s), fps)
        states += [start.state] * grid[1]
        controls += [control] * grid[1]
    out = rollout_batch(character, character.stack_styles([c for row in styles_SxR1 for c in row]),
                        loop.stack_trees(states), loop.stack_trees(controls))
    positions = np.asarray(out.positions)[:, :, :judging.skeleton.num_joints]
    origin = np.asarray(out.origin)
    finite = np.isfinite(positions).all(axis=(1, 2, 3)) & np.isfinite(np.asarray(out.outputs)).all(axis=(1, 2))
    return judge_pairs(positions.reshape(grid + positions.shape[1:]), origin.reshape(grid + origin.shape[1:]),
                       finite.reshape(grid), judging,
                       Captures([s.floor for s in starts], np.array([s.speed for s in starts], float),
                                np.array([s.contact_fraction for s in starts], float)))


def passes_check(out: dict[str, np.ndarray], real_contact_fraction_S, base_skating_m_s_S, speed_m_s_S,
                 check: RolloutCheck) -> np.ndarray:
    """``(S, R)`` whether each pair passes the :class:`RolloutCheck`, from the pairs' measures
    ``out`` (``(S, R)`` arrays of :func:`rollout_measures`) and per style ``(S,)``: the capture's
    share of frames with a foot on the floor, the skating of the model before fine-tuning on the
    same path (NaN where its rollout diverged: not judged against it) and the style's speed (m/s;
    a style that stands still is not held to the distance). A pair passes when
    :func:`failed_criteria`, the one statement of the rule, finds nothing."""
    fields = ("finite", "bone_error", "contact_fraction", "skating_m_s", "progress")
    num_styles, num_rates = np.shape(out["finite"])
    return np.array([[not failed_criteria({k: float(out[k][s, r]) for k in fields}, float(real_contact_fraction_S[s]),
                                          float(base_skating_m_s_S[s]), float(speed_m_s_S[s]), check)
                      for r in range(num_rates)] for s in range(num_styles)], dtype=bool).reshape(num_styles, num_rates)


def failed_criteria(measures: dict[str, float], real_contact_fraction: float, base_skating_m_s: float,
                    speed_m_s: float, check: RolloutCheck) -> list[str]:
    """The criteria of the :class:`RolloutCheck` that one pair fails, each as one phrase with its
    figure and limit (``[]`` when it passes; :func:`passes_check` applies it to every pair):
    ``measures`` are one pair's figures of :func:`rollout_measures`, the others as in
    :func:`passes_check` (a NaN figure fails its criterion; a NaN base skating is not judged against)."""
    if not measures.get("finite", 0.0):
        return ["the rollout did not stay finite"]
    out = []
    bone, contact, skating, progress = (float(measures[k]) for k in ("bone_error", "contact_fraction",
                                                                        "skating_m_s", "progress"))
    if not bone <= check.max_bone_error:
        out.append(f"bone error {bone:.3f} > {check.max_bone_error:g}")
    if not contact >= check.min_contact_ratio * real_contact_fraction:
        out.append(f"feet on the floor {contact:.2f} of frames < {check.min_contact_ratio:g} x the clip's "
                   f"{real_contact_fraction:.2f}")
    limit = check.max_skating_ratio * base_skating_m_s + check.skating_slack_m_s
    if np.isfinite(base_skating_m_s) and not np.isnan(skating) and not skating <= limit:
        out.append(f"foot skating {skating:.2f} m/s > {limit:.2f} ({check.max_skating_ratio:g} x the base's "
                   f"{base_skating_m_s:.2f} + {check.skating_slack_m_s:g})")
    if not speed_m_s < 0.1 and not check.min_progress <= progress <= 1.0 / check.min_progress:
        out.append(f"travelled {progress:.2f} of the path (outside {check.min_progress:g} .. "
                   f"{1.0 / check.min_progress:g})")
    return out


FAILED_MARK = " [FAILED CHECK]"
"""Appended to the title of a character whose new style failed the closed-loop check at every
rate, when it is used anyway (``--allow-failed``): every table names it so."""


def failed_check(info: dict, name: str) -> str | None:
    """``None`` when the new style ``name`` passed the closed-loop check at its chosen rate, else one
    line naming it and what failed. ``info``: its entry of a sweep's ``chosen_rates.json`` (the 2018
    sweep's ``passed_check``, the 2022 clip sweep's ``check_passed``; ``failed``: the criteria)."""
    if info.get("passed_check", info.get("check_passed", True)):
        return None
    what = "; ".join(info.get("failed", [])) or "see the sweep's results"
    return f"{name} failed the closed-loop check at every rate (at its chosen rate {info['rate']:g}: {what})"


def refusal(kind: str, failed: str) -> str:
    """The one line that refuses a style whose check failed (``failed``: :func:`failed_check`'s
    line; ``kind``: "few-shot set", "new style") in ``synthesize`` and ``demo``."""
    return f"{kind} {failed}; it is not used (--allow-failed uses it anyway, marked in the tables)"


def choose_rates(validation_loss_SxR: np.ndarray, passed_SxR: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Per style the index of the chosen rate and whether it passed the closed-loop check: the
    lowest finite validation loss among the rates that passed, else among all rates (flagged as
    not passed; the first rate when no loss is finite). ``passed_SxR=None``: validation alone (every
    rate counts as passed; the flag then says whether the style has a finite loss)."""
    val = np.where(np.isfinite(validation_loss_SxR), validation_loss_SxR, np.inf)
    passed = np.ones(val.shape, bool) if passed_SxR is None else np.asarray(passed_SxR).astype(bool)
    masked = np.where(passed, val, np.inf)
    any_pass = np.isfinite(masked).any(axis=1)
    chosen = np.where(any_pass, np.argmin(masked, axis=1), np.argmin(val, axis=1)).astype(np.int32)
    return chosen, any_pass
