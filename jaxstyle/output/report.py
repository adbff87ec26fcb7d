"""The quality benchmark's report over the rows of :mod:`jaxstyle.output.quality`: the targets
checked against each style's capture (:func:`targets`, :func:`target_summary`, :func:`target_marks`),
the markdown table (:func:`table`, with the stalled-phases and style-shows marks), the CSV
(:func:`write_csv`), the bars of generated against capture (:func:`plot`) and the comparison of
foot locking with the plain contact IK on the same rollouts (:func:`lock_comparison`).
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from jaxstyle.output.measure import SLIDING_SOURCES
from jaxstyle.output.quality import FOLLOW_PATHS, MODEL_2018, NOT_STEPPING_MARK, PATH_TARGETS, STALLED_MARK


def _model(r: dict) -> str:
    return r.get("model") or MODEL_2018


def _capture_of(rows: list[dict]) -> dict[tuple[str, str], dict]:
    """The capture row of each ``(model, style)``."""
    return {(_model(r), r["style"]): r for r in rows if r["path"] == "capture"}


LOCK_TARGETS = ("locked skating <= capture + 0.03", "foot offset <= 0.15 m", "foot below floor <= 0.01 m",
                "steps/s within 25% of capture", "stance fraction within 0.15 of capture",
                "locked ankle jerk <= 1.5x capture", "lifted steps/s within 25% of capture")
"""The foot-locking targets :func:`targets` checks (their names), beside
:data:`jaxstyle.output.quality.PATH_TARGETS`."""


STYLE_TARGET = "style distance < half capture's to Neutral"
"""The style-fidelity target (:mod:`jaxstyle.output.style`): a character's distance to its own
capture below half its capture's distance to Neutral's capture."""


def targets(rows: list[dict]) -> list[dict]:
    """One entry per (target, character, path): ``{"target", "model", "style", "path", "value",
    "limit", "met"}``. Against the style's capture: raw skating (1.5x for base styles, 2x for
    few-shot) and :data:`LOCK_TARGETS` (skating after locking at most the capture's + 0.03 m/s,
    ``steps_per_s`` within 25% and ``stance_fraction`` within 0.15 of the capture's, ankle jerk
    after locking at most 1.5x, ``lifted_steps_per_s`` within 25% of the capture's; the value of the
    three "within" targets is the difference from the capture); on every row: no foot moved more
    than 0.15 m by the lock, none more than 1 cm below the floor; final path error <= 0.3 m on
    straight, circle and zigzag, stop within 0.5 s, BVH bone error 0; and for every style but
    Neutral :data:`STYLE_TARGET` (the style shows)."""
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
            lifted, ref = r.get("lifted_steps_per_s", nan), c.get("lifted_steps_per_s", nan)
            add(LOCK_TARGETS[6], r, abs(lifted - ref) / ref if ref > 0 else nan, 0.25)
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
        lines.append(f"| {model} | {name} | {met} / {len(mine)} | {figure(worst['value'], 3)} vs "
                     f"{figure(worst['limit'], 3)} ({worst['style']}, {worst['path']}) |")
    return lines


def target_marks(checks: list[dict], names: Sequence[str] = PATH_TARGETS) -> list[str]:
    """Markdown lines: every check of the targets ``names`` (default the path and stop targets)
    with its value, its limit and a pass/FAIL mark, then one line counting them (and each target's
    count when there are several)."""
    mine = [c for c in checks if c["target"] in names]
    lines = ["| model | style | path | target | value | limit | |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {c.get('model', MODEL_2018)} | {c['style']} | {c['path']} | {c['target']} | "
              f"{figure(c['value'], 2)} | {figure(c['limit'], 2)} | {'pass' if c['met'] else 'FAIL'} |" for c in mine]
    met = sum(c["met"] for c in mine)
    blank = sum(not np.isfinite(c["value"]) for c in mine)
    note = f" ({blank} n/a: never stopped before the path moved on or ended, or a diverged rollout)" if blank else ""
    each = [f"{n} {sum(c['met'] for c in mine if c['target'] == n)}/{sum(c['target'] == n for c in mine)}"
            for n in names if any(c["target"] == n for c in mine)]
    detail = f" ({'; '.join(each)})" if len(each) > 1 else ""
    return lines + ["", f"{', '.join(names)}: {met} of {len(mine)} met{note}{detail}"]


def figure(v, digits: int = 2) -> str:
    """A table cell: ``v`` with ``digits`` decimals, ``n/a`` when it is missing (``None``, or a
    CSV row's blank) or not finite. The benchmark's tables here, ``jaxstyle synthesize``'s
    (:func:`jaxstyle.output.synthesis.quality_table`) and ``jaxstyle lpn``'s closing check
    (:func:`jaxstyle.mason2022.report.style_check_table`) write their figures with it."""
    return "n/a" if v is None or v == "" or not np.isfinite(float(v)) else f"{float(v):.{digits}f}"


def table(rows: list[dict]) -> list[str]:
    """The benchmark's markdown table: per model (in order of appearance) and style, its capture
    row (naming the capture's file), then one row per path."""
    head = ("| model | style | path | skating m/s net / BVH / locked | steps/s locked, lifted (BVH) | stance | "
            "slide/contact m | foot offset m | below floor m | bone error net max / BVH | "
            "path error mean / final m (final %) | heading deg | stop s | jitter m/s^3 | "
            "ankle jerk net / locked m/s^3 | style distance m (shows) / capture: halves, to Neutral |")
    lines = [head, "|" + "---|" * 16]
    order = {m: i for i, m in enumerate(dict.fromkeys(_model(r) for r in rows))}
    for r in sorted(rows, key=lambda r: (order[_model(r)], r["style"], r["path"] != "capture")):
        g = r.get
        path = f"capture ({r['capture_file']})" if r["path"] == "capture" and g("capture_file") else r["path"]
        path += stalled_mark(r)  # the closed loop or the feet froze: said, not hidden
        lines.append(
            f"| {_model(r)} | {r['style']} | {path} | {figure(r['foot_skating_m_s'])} / "
            f"{figure(r['foot_skating_bvh_m_s'])} / {figure(g('foot_skating_locked_m_s'))} | "
            f"{figure(g('steps_per_s'))}, {figure(g('lifted_steps_per_s'))} ({figure(g('steps_per_s_bvh'))}) | "
            f"{figure(g('stance_fraction'))} | "
            f"{figure(g('slide_per_contact_m'), 3)} | {figure(g('ik_foot_offset_max_m'), 3)} | "
            f"{figure(g('foot_below_floor_m'), 3)} | "
            f"{100 * g('bone_error_max', math.nan):.1f}% / {100 * g('bone_error_bvh_max', math.nan):.1g}%"
            f" | {figure(g('path_error_mean_m'))} / "
            f"{figure(g('path_error_final_m'))} ({figure(g('path_error_final_pct'), 1)}%) | "
            f"{figure(g('heading_error_deg'), 1)} | {figure(g('stop_time_s'))} | {figure(g('jitter_m_s3'), 0)} | "
            f"{figure(g('ankle_jerk_m_s3'), 0)} / {figure(g('ankle_jerk_locked_m_s3'), 0)} | {_style_cell(r)} |")
    return lines


def _style_cell(r: dict) -> str:
    """The style-distance cell of :func:`table`: a character's distance to its capture and whether its
    style shows; a capture's distance between its halves and to Neutral's capture."""
    g = r.get
    if r["path"] == "capture":
        return f"{figure(g('style_halves_distance', math.nan))}, {figure(g('style_to_neutral', math.nan))}"
    return f"{figure(g('style_distance', math.nan))}{shows_mark(r)}"


def stalled_mark(r: dict) -> str:
    """`` [PHASES STALLED]`` (:data:`jaxstyle.output.quality.STALLED_MARK`) for a row (or a CSV row) whose local phases
    stalled (:func:`jaxstyle.output.quality.phase_figures`) and `` [NOT STEPPING]``
    (:data:`jaxstyle.output.quality.NOT_STEPPING_MARK`) for one whose character hardly lifts its feet while
    it moves (:func:`jaxstyle.output.quality.stepping_figures`); nothing for a row with neither."""
    marks = [STALLED_MARK] if r.get("phases_stalled") in (True, "True") else []
    if r.get("not_stepping") in (True, "True"):
        marks.append(NOT_STEPPING_MARK)
    return "".join(f" {m}" for m in marks)


def shows_mark(r: dict) -> str:
    """`` (shows)`` or `` (no)`` for a row (or a CSV row) whose ``style_shows`` is set
    (:func:`jaxstyle.output.quality.style_figures`), else nothing (Neutral, the reference, and the captures' rows)."""
    shows = r.get("style_shows")
    return "" if shows is None or shows == "" else (" (shows)" if shows in (True, "True") else " (no)")


def write_csv(rows: list[dict], path: str | os.PathLike) -> Path:
    """The rows as CSV (columns: the union of the rows' keys, blank where absent)."""
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
    """Markdown lines comparing, on the same rollouts, the plain contact IK
    (:func:`jaxstyle.output.measure.pinned_feet`) with foot locking: per model, how many (character,
    path) rows meet each foot target after each, the medians, and where the skating left after
    locking comes from (median shares of :func:`jaxstyle.output.measure.sliding_sources`)."""
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
                return "" if key is None else figure(float(np.nanmedian([r.get(key, math.nan) for r in mine])), digits)

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
            shares = [figure(float(np.nanmedian([r[f"sliding_{k.replace(', ', '_')}"] for r in mine])))
                      for k in SLIDING_SOURCES]
            lines.append(f"| {model} | " + " | ".join(shares) + " |")
    return lines
