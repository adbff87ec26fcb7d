"""The 2022 workflow's reports: Markdown tables of models' losses, budgets and Table 2's ordering
(:func:`losses_table`, :func:`models_table`, :func:`budget_table`, :func:`ordering_lines`), of a FiLM
fine-tuning sweep and its closed-loop check (:func:`finetune_summary`, :func:`finetune_table`,
:func:`check_table`), and figures (:func:`curves_figure`: validation curves of several models;
:func:`film_figure`: the paper's Figure 11 with PCA).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from jaxstyle.mason2022.finetune import FinetuneResult
from jaxstyle.mason2022.pipeline import BudgetRun, Model, ModelRuns
from jaxstyle.nn import film_generator as film
from jaxstyle.output import viz


def budget_table(runs: dict[str, BudgetRun], logs: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Markdown lines: per model the epochs it got in its budget and why it stopped, its minutes,
    the last epoch's training MSE and validation MSE, its best validation MSE, and every model's
    validation MSE at the epoch all of them reached (a comparison at equal epochs)."""
    common = min((len(log["epoch"]) for log in logs.values() if log), default=0)
    lines = [f"| model | epochs | stopped | minutes | train MSE (last epoch) | val MSE (last) | best val MSE | "
             f"val MSE @ epoch {common} |", "|---|---|---|---|---|---|---|---|"]
    for name, run in runs.items():
        log = logs[name]
        lines.append(f"| {name} | {run.epochs} | {run.stopped} | {run.seconds / 60:.1f} | {log['train_mse'][-1]:.4f} | "
                     f"{log['val_mse'][-1]:.4f} | {np.nanmin(log['val_mse']):.4f} | "
                     f"{log['val_mse'][common - 1]:.4f} |")
    return lines


def model_line(name: str, done: ModelRuns) -> str:
    """One line on a model just trained by :func:`jaxstyle.mason2022.pipeline.train_models`: its
    epochs, why it stopped, its minutes, its last validation MSE and its test MSE."""
    run, log = done.runs[name], done.logs[name]
    return (f"{name}: {run.epochs} epochs ({run.stopped}) in {run.seconds / 60:.1f} min; validation MSE "
            f"{log['val_mse'][-1]:.4f}; test MSE {np.mean(done.results[name]['mse']):.4f}")


def ordering_lines(results: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Lines: the models ranked by mean test MSE + BLL, and whether the paper's two claims about
    Figure 10 hold: every FiLM model has a lower test error than every one-hot and adapter model,
    and PFNN Resad is below LPN Resad (the CP adapter's phase dependence)."""
    total = {n: float(np.mean(r["mse"]) + np.mean(r["bll"])) for n, r in results.items()}
    ranked = sorted(total, key=total.get)
    lines = ["ranked by test MSE + BLL (lowest first): " + ", ".join(f"{n} {total[n]:.4f}" for n in ranked)]
    film_models = [n for n in total if "FiLM" in n]
    other = [n for n in total if "FiLM" not in n]
    if film_models and other:
        worst_film, best_other = max(film_models, key=total.get), min(other, key=total.get)
        holds = total[worst_film] < total[best_other]
        verdict = "holds" if holds else "does not hold"
        lines.append(f"paper: every FiLM model below every one-hot / adapter model: {verdict}"
                     f" (worst FiLM {worst_film} {total[worst_film]:.4f}, best other {best_other} "
                     f"{total[best_other]:.4f})")
    if {"PFNN Resad", "LPN Resad"} <= set(total):
        holds = total["PFNN Resad"] < total["LPN Resad"]
        lines.append(f"paper: PFNN Resad below LPN Resad: {'holds' if holds else 'does not hold'} "
                     f"({total['PFNN Resad']:.4f} vs {total['LPN Resad']:.4f})")
    return lines


def _median(values) -> float:
    """The median of the finite values (NaN when there is none, e.g. a model without local phases)."""
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else np.nan


def closed_loop_figures(rows: list[dict]) -> dict[str, dict]:
    """Per model (the ``model`` of rows of :func:`jaxstyle.output.quality.run`, its capture rows
    included) the closed-loop figures that tell stepping from gliding: ``rows`` driven,
    ``diverged`` (a non-finite rollout), ``stalled`` (local phases stalled,
    :func:`jaxstyle.output.quality.phase_figures`), ``stepping`` (steps per second of the locked
    skeleton within 25% of its capture's), ``lifted_stepping`` (the same of
    ``lifted_steps_per_s``, :class:`jaxstyle.output.metrics.StepFigures`), ``not_stepping`` (feet
    lifted at under half the capture's rate while moving, :func:`jaxstyle.output.quality.stepping_figures`;
    the runtime's phase floor can hide such a row from ``stalled``), ``gliding`` (feet on the
    floor over 95% of frames where its capture's are not), the medians over rows of
    ``steps_ratio``, ``skating_ratio`` (raw foot skating of the network's joints over its
    capture's), ``phase_rate_ratio`` (the local phases' advance over the capture's),
    ``style_distance`` (m), ``wrist_range_ratio``, and ``shows`` / ``styled`` (rows whose style
    shows, of the rows of a style other than Neutral)."""
    captures = {(r["model"], r["style"]): r for r in rows if r["path"] == "capture"}
    out = {}
    for model in dict.fromkeys(r["model"] for r in rows):
        mine = [(r, captures[(model, r["style"])]) for r in rows if r["model"] == model and r["path"] != "capture"]
        finite = [(r, c) for r, c in mine if r.get("finite", True)]
        steps = np.array([r["steps_per_s"] / c["steps_per_s"] for r, c in finite])
        lifted = np.array([r.get("lifted_steps_per_s", np.nan) / c.get("lifted_steps_per_s", np.nan)
                           for r, c in finite])
        styled = [r for r, _ in finite if r.get("style_shows") is not None]
        out[model] = {
            "rows": len(mine), "diverged": len(mine) - len(finite),
            "stalled": sum(bool(r.get("phases_stalled")) for r, _ in finite),
            "not_stepping": sum(bool(r.get("not_stepping")) for r, _ in finite),
            "stepping": int(np.sum(np.abs(steps - 1.0) <= 0.25)),
            "lifted_stepping": int(np.sum(np.abs(lifted - 1.0) <= 0.25)),
            "gliding": sum(r["contact_fraction"] > 0.95 >= c["contact_fraction"] for r, c in finite),
            "steps_ratio": float(np.median(steps)) if len(steps) else np.nan,
            "skating_ratio": float(np.median([r["foot_skating_m_s"] / c["foot_skating_m_s"] for r, c in finite]))
            if finite else np.nan,
            "phase_rate_ratio": _median([r.get("phase_rate_ratio", np.nan) for r, _ in finite]),
            "style_distance": _median([r["style_distance"] for r, _ in finite]),
            "wrist_range_ratio": _median([r["wrist_range_ratio"] for r, _ in finite]),
            "shows": sum(bool(r["style_shows"]) for r in styled), "styled": len(styled)}
    return out


def closed_loop_table(figures: dict[str, dict], results: dict[str, dict[str, np.ndarray]] | None = None) -> list[str]:
    """Markdown lines of :func:`closed_loop_figures`, one row per model, with its test MSE + BLL
    from ``results`` (:func:`jaxstyle.mason2022.pipeline.model_losses` per model) where given."""
    lines = ["| model | test MSE + BLL | rows stepping within 25%: onsets, lifted | median steps/s / capture | "
             "rows gliding | rows stalled | rows not stepping | median raw skating / capture | "
             "median style distance m | styles shown | median wrist range / capture | diverged |",
             "|---|" + "---|" * 11]
    for name, f in figures.items():
        loss = (f"{np.mean(results[name]['mse']) + np.mean(results[name]['bll']):.4f}"
                if results and name in results else "-")
        n = f["rows"] - f["diverged"]
        lines.append(f"| {name} | {loss} | {f['stepping']}, {f['lifted_stepping']} / {n} | {f['steps_ratio']:.2f} | "
                     f"{f['gliding']} / {n} | {f['stalled']} / {n} | {f['not_stepping']} / {n} | "
                     f"{f['skating_ratio']:.1f} | {f['style_distance']:.2f} | "
                     f"{f['shows']} / {f['styled']} | {f['wrist_range_ratio']:.2f} | {f['diverged']} / {f['rows']} |")
    return lines


def epoch_choice_table(choice) -> list[str]:
    """Markdown lines of a :class:`jaxstyle.mason2022.synthesis.EpochChoice`: one row per epoch
    compared, its training styles' lifted steps over their captures' on the check
    (``lifted_step_ratio``), the styles within 25% of the capture's, those not stepping, and which
    epoch was chosen."""
    from jaxstyle.mason2022.synthesis import epoch_score
    from jaxstyle.output.report import figure

    styles = list(dict.fromkeys(s for r in choice.ratios.values() for s in r))
    lines = ["| epoch | " + " | ".join(styles) + " | within 25% | not stepping | |",
             "|---|" + "---|" * (len(styles) + 3)]
    for epoch, ratios in sorted(choice.ratios.items()):
        within, still = epoch_score(ratios)
        lines.append(f"| {epoch} | " + " | ".join(figure(ratios.get(s)) for s in styles)
                     + f" | {within} | {-still} | {'chosen' if epoch == choice.epoch else ''} |")
    return lines


def style_check_table(rows: list[dict]) -> list[str]:
    """Markdown lines of :func:`jaxstyle.mason2022.synthesis.style_check`'s rows: per style its
    lifted steps per second beside its capture's and their ratio over the moving frames
    (``lifted_step_ratio``), contact onsets, feet on the floor, raw skating over the capture's, the
    style distance (and whether the style shows) and the marks of
    :func:`jaxstyle.output.report.stalled_mark`; then one line naming the styles not stepping, or
    saying that every style steps."""
    from jaxstyle.output.quality import STEP_RATIO
    from jaxstyle.output.report import figure, shows_mark, stalled_mark

    captures = {r["style"]: r for r in rows if r["path"] == "capture"}
    lines = ["| style | lifted steps/s (capture) | lifted / capture while moving | onsets/s (capture) | "
             "feet on floor (capture) | raw skating / capture | style distance m |", "|---|" + "---|" * 6]
    still = []
    for r in rows:
        if r["path"] == "capture":
            continue
        c = captures[r["style"]]
        if not r.get("finite", True):
            lines.append(f"| {r['style']} (diverged) |" + " n/a |" * 6)
            still.append(r["style"])
            continue
        if r.get("not_stepping"):
            still.append(r["style"])
        lines.append(f"| {r['style']}{stalled_mark(r)} | "
                     f"{figure(r['lifted_steps_per_s'])} ({figure(c['lifted_steps_per_s'])}) | "
                     f"{figure(r['lifted_step_ratio'])} | {figure(r['steps_per_s'])} ({figure(c['steps_per_s'])}) | "
                     f"{figure(r['contact_fraction'])} ({figure(c['contact_fraction'])}) | "
                     f"{figure(r['foot_skating_m_s'] / c['foot_skating_m_s'], 1)} | "
                     f"{figure(r.get('style_distance'))}{shows_mark(r)} |")
    lines.append("")
    lines.append(f"not stepping (lifted steps under {STEP_RATIO:g} of the capture's, or diverged): {', '.join(still)}"
                 if still else f"every style steps (lifted steps at least {STEP_RATIO:g} of its capture's)")
    return lines


def closed_loop_ordering_lines(figures: dict[str, dict], best: str = "LPN FiLM") -> list[str]:
    """Lines: whether ``best`` (the paper's model) is at least as good as every other model of
    ``figures`` (:func:`closed_loop_figures`) in the closed loop: the most rows stepping within 25%
    of their captures, the lowest median raw skating ratio, the lowest median style distance; and
    whether every FiLM model's median style distance is below every one-hot / adapter model's (the
    paper's section 5.1 finds FiLM models the better stylists by eye; it gives no closed-loop
    figures)."""
    if best not in figures or len(figures) < 2:
        return []
    lines = []
    for key, label, sign in (("stepping", "most rows stepping within 25% of the capture", -1),
                             ("skating_ratio", "lowest median raw skating / capture", 1),
                             ("style_distance", "lowest median style distance", 1)):
        value = {n: sign * f[key] for n, f in figures.items() if np.isfinite(f[key])}
        if best not in value:
            continue
        top = min(value, key=value.get)
        holds = value[best] <= value[top]
        shown = {n: f"{sign * v:.0f}" if key == "stepping" else f"{sign * v:.2f}" for n, v in value.items()}
        lines.append(f"{best} {label}: {'holds' if holds else 'does not hold'} ({best} {shown[best]}"
                     + ("" if holds else f", best {top} {shown[top]}") + ")")
    film_models = {n: f["style_distance"] for n, f in figures.items() if "FiLM" in n}
    other = {n: f["style_distance"] for n, f in figures.items() if "FiLM" not in n}
    if film_models and other:
        worst, top = max(film_models, key=film_models.get), min(other, key=other.get)
        holds = film_models[worst] < other[top]
        lines.append(f"every FiLM model's median style distance below every one-hot / adapter model's: "
                     f"{'holds' if holds else 'does not hold'} (worst FiLM {worst} {film_models[worst]:.2f}, "
                     f"best other {top} {other[top]:.2f})")
    return lines


def curves_figure(logs: dict[str, dict[str, np.ndarray]], path: str | os.PathLike, *, title: str = "") -> Path:
    """One figure of validation curves of several runs (``{model: read_log(...)}``): validation MSE
    against epochs (left) and against cumulative training minutes (right), log scale."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for i, (name, log) in enumerate(logs.items()):
        if not log:
            continue
        style = {"color": f"C{i}", "marker": "o", "markersize": 3, "label": name,
                 "linestyle": "-" if "FiLM" in name else "--"}
        a.plot(log["epoch"], log["val_mse"], **style)
        b.plot(np.cumsum(log["seconds"]) / 60.0, log["val_mse"], **style)
    a.set_xlabel("epoch")
    b.set_xlabel("training minutes (2-core CPU, validation included)")
    a.set_ylabel("validation MSE (normalised outputs)")
    for ax in (a, b):
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
    a.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path



def check_table(result: "FinetuneResult", checked: dict[str, np.ndarray]) -> list[str]:
    """Markdown lines: per clip style and rate the validation loss (``(fails)`` where the
    closed-loop check fails), the chosen rate and its check's figures."""
    rates = result.rates
    val = result.after["validation"]["mse"] + result.after["validation"]["bll"]
    lines = ["| clip style | val rows | " + " | ".join(f"val @ {r:g}" for r in rates)
             + " | chosen | check | bone error | feet on floor (clip) | skating m/s (before) | progress |",
             "|---|---|" + "---|" * len(rates) + "---|---|---|---|---|---|"]
    for s, style in enumerate(result.styles):
        c = int(result.chosen[s])
        cells = [f"{val[s, r]:.4f}" + ("" if checked["passed"][s, r] else " (fails)") for r in range(len(rates))]
        lines.append(f"| {style} | {len(result.data.val_rows[s])} | " + " | ".join(cells)
                     + f" | {rates[c]:g} | {'passed' if checked['chosen_passed'][s] else 'FAILED'} | "
                       f"{100 * checked['bone_error'][s, c]:.1f}% | {checked['contact_fraction'][s, c]:.2f} "
                       f"({checked['real_contact_fraction'][s]:.2f}) | {checked['skating_m_s'][s, c]:.2f} "
                       f"({checked['base_skating_m_s'][s]:.2f}) | {checked['progress'][s, c]:.2f} |")
    return lines



def losses_table(styles: Sequence[str], losses: dict[str, np.ndarray]) -> list[str]:
    """Markdown lines: one model's test MSE and bone-length loss per style."""
    lines = ["| style | test MSE (normalised) | test bone-length loss (cm) |", "|---|---|---|"]
    return lines + [f"| {style} | {losses['mse'][s]:.4f} | {100 * losses['bll'][s]:.2f} |"
                    for s, style in enumerate(styles)]


def models_table(styles: Sequence[str], results: dict[str, dict[str, np.ndarray]]) -> list[str]:
    """Markdown lines: per model its mean test MSE and bone-length loss, and both per style."""
    lines = ["| model | test MSE (normalised) | test BLL (m) | " + " | ".join(styles) + " |",
             "|---|---|---|" + "---|" * len(styles)]
    for name, r in results.items():
        per = " | ".join(f"{m:.3f} / {b * 100:.2f} cm" for m, b in zip(r["mse"], r["bll"], strict=True))
        lines.append(f"| {name} | {np.mean(r['mse']):.4f} | {np.mean(r['bll']):.5f} | {per} |")
    return lines


def finetune_summary(result: FinetuneResult) -> str:
    """One line: what was fine-tuned, and how long it took."""
    return (f"fine-tuned the FiLM generator alone: {len(result.styles)} new styles x {len(result.rates)} rates, "
            f"{result.steps} steps each, one compiled sweep: {result.seconds:.0f} s")


def finetune_table(result: FinetuneResult, *, checked: bool = False) -> list[str]:
    """Markdown lines: per new style its test MSE before and after fine-tuning at each rate, the
    chosen rate and the test bone-length loss there; then the validation loss that chose it
    (``checked``: among the rates that passed the closed-loop check, :func:`finetune_clips`) and,
    when the rates were chosen by walking every pair
    (:func:`jaxstyle.mason2022.synthesis.choose_stepping_rates`), each pair's lifted steps over the
    capture's."""
    from jaxstyle.output.quality import STEP_RATIO

    rates, s_r = result.rates, range(len(result.rates))
    test, val = result.after["test"], result.after["validation"]
    lines = ["| new style | test MSE before | " + " | ".join(f"after @ {r:g}" for r in rates)
             + " | chosen rate | test BLL before / after (cm) |", "|---|---|" + "---|" * len(rates) + "---|---|"]
    for s, style in enumerate(result.styles):
        c = int(result.chosen[s])
        lines.append(f"| {style} | {result.before['test']['mse'][s]:.4f} | "
                     + " | ".join(f"{test['mse'][s, r]:.4f}" for r in s_r)
                     + f" | {rates[c]:g} | {100 * result.before['test']['bll'][s]:.2f} / "
                       f"{100 * test['bll'][s, c]:.2f} |")
    lines += ["", "| new style | validation MSE + BLL before | " + " | ".join(f"@ {r:g}" for r in rates) + " |",
              "|---|---|" + "---|" * len(rates)]
    for s, style in enumerate(result.styles):
        before = result.before["validation"]["mse"][s] + result.before["validation"]["bll"][s]
        cells = [f"{val['mse'][s, r] + val['bll'][s, r]:.4f}" + (" (chosen)" if r == result.chosen[s] else "")
                 for r in s_r]
        lines.append(f"| {style} | {before:.4f} | " + " | ".join(cells) + " |")
    walked = result.lifted_step_ratio
    if walked is not None:
        lines += ["", "| new style | " + " | ".join(f"lifted steps / capture's @ {r:g}" for r in rates) + " |",
                  "|---|" + "---|" * len(rates)]
        for s, style in enumerate(result.styles):
            cells = [f"{walked[s, r]:.2f}" + (" (chosen)" if r == result.chosen[s] else "") for r in s_r]
            lines.append(f"| {style} | " + " | ".join(cells) + " |")
    if checked:
        rule = " among the rates that pass the closed-loop check, or among all when none passes"
    elif walked is not None:
        rule = (" among the rates whose walk along a straight line lifts its feet within 25% of the capture's rate, "
                f"else among those stepping (at least {STEP_RATIO:g} of it), else among all")
    else:
        rule = "; a style without validation rows keeps the first rate"
    lines.append(f"\n(the validation rows choose the rate{rule})")
    return lines


def film_figure(model: Model, result: FinetuneResult, path: str | os.PathLike, *, clips_per_style: int = 50) -> Path:
    """The paper's Figure 11 with PCA: FiLM parameters of up to ``clips_per_style`` training clips of
    every style before and after fine-tuning (new styles at their chosen rates), written to ``path``."""
    gen0 = model.params["style"]["generator"]
    before, after = {}, {}
    for s, style in enumerate(model.data.styles):
        c = model.data.train_clips[s][:clips_per_style]
        before[style] = after[style] = film.clip_films(gen0, model.data.clips[c])
    for s, style in enumerate(result.styles):
        c = result.data.train_clips[s][:clips_per_style]
        before[style] = film.clip_films(gen0, result.data.clips[c])
        after[style] = film.clip_films(result.params(model, style)["style"]["generator"], result.data.clips[c])
    fig = viz.plot_film_projection({"before fine-tuning": before, "after fine-tuning": after},
                                   new_styles=result.styles, title="FiLM parameters of style clips (PCA)")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    import matplotlib.pyplot as plt  # after viz chose the backend

    plt.close(fig)
    return path
