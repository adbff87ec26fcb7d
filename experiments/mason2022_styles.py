"""Train all seven style models of Table 2 on the shared 100STYLE clips within one time budget, test
them, and fine-tune LPN-FiLM on held-out styles (Mason, Starke & Komura 2022, sections 4.3, 5.2.2
and 5.3).

    python experiments/mason2022_styles.py [--minutes 60] [--models "PFNN One-hot,...,LPN FiLM"]
        [--new-styles Elated,Rushed] [--finetune-steps 150] [--out runs/mason2022]

The pipeline of ``jaxstyle lpn`` (:mod:`jaxstyle.mason2022.pipeline`) for several models:

1. Data: the shared 100STYLE styles except ``--new-styles`` (every gait, mirrored where symmetric,
   80/10/10 splits per clip), with the local phases and the global phase of every row; the new
   styles normalised with the base's statistics.
2. Budget: ``--minutes`` of wall-clock time for the whole run (data included). The rule: the time
   left is split evenly over the jobs left (each model of ``--models``, in order, then the
   fine-tuning sweep), so a model that stops early hands its unused time to the jobs after it.
   A model trains whole epochs (:func:`jaxstyle.mason2022.pipeline.train_for`) while the next one
   fits its share, at least one, at most ``--max-epochs`` (the paper: 90), and stops early once its
   validation loss has flattened (less than 1% better over the last 3 epochs). The default order
   puts the cheap one-hot and adapter models first and the FiLM models last.
3. Each model is tested: normalised MSE and bone-length loss per style (resumes from
   ``--out/<model>``; a second run with a larger ``--minutes`` continues the same runs).
4. New styles: the FiLM generator of LPN FiLM alone is fine-tuned for every (new style, dropout
   rate) pair in one compiled sweep; its steps fit the sweep's share of the budget (estimated
   from LPN FiLM's measured step time, at most ``--finetune-steps``); the rate with the lowest
   validation loss is kept.
5. ``curves.png``: validation MSE of all models against epochs and against training minutes;
   ``figure11.png``: FiLM parameters of style clips before and after fine-tuning, PCA (the paper's
   Figure 11 uses t-SNE); ``chosen_rates.json`` and ``finetuned_generators.npz``.

Prints Markdown tables and writes them to ``--out/results.md``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import jaxstyle as js
from jaxstyle.data import clips, folders
from jaxstyle.mason2022 import finetune, pipeline, report
from jaxstyle.train import defaults

ORDER = ("PFNN One-hot", "LPN One-hot", "PFNN Resad", "LPN Resad", "LPN FiLM", "PFNN FiLM", "MANN FiLM")
"""The default order: the cheap one-hot and adapter models first (time they leave unused goes to the
FiLM models), then the paper's model, then the other FiLM backbones."""
SWEEP_STEP_COST = 1.5
"""A fine-tuning step of one (style, rate) pair, in LPN-FiLM training steps (measured 2026-11-22:
836 s for 150 steps x 6 pairs against about 0.6 s per training step)."""


def names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def main() -> None:
    t_start = time.perf_counter()
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", type=names, default=",".join(ORDER))
    parser.add_argument("--new-styles", type=names, default=",".join(pipeline.PAPER_NEW_STYLES))
    parser.add_argument("--minutes", type=float, default=60.0, help="wall-clock budget of the whole run")
    parser.add_argument("--max-epochs", type=int, default=90, help="at most this many epochs per model (paper: 90)")
    parser.add_argument("--finetune-steps", type=int, default=150, help="at most this many steps per (style, rate)")
    parser.add_argument("--rates", type=float, nargs="+", default=list(defaults.FILM_DEFAULT_RATES))
    parser.add_argument("--max-seconds", type=float, help="use only the first seconds of each clip (quick checks)")
    parser.add_argument("--data", type=Path, help="a style folder (default: the shared 100STYLE sample)")
    parser.add_argument("--hidden", type=int, default=512, help="hidden units (paper: 512; smaller: quick checks)")
    parser.add_argument("--generator-hidden", type=int, default=2048, help="FiLM generator's dense units (paper: 2048)")
    parser.add_argument("--filters", type=int, default=256, help="FiLM generator's convolution filters (paper: 256)")
    parser.add_argument("--out", type=Path, default=Path("runs/mason2022"))
    parser.add_argument("--cache", type=Path, default=Path("runs/cache"))
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args()
    deadline = t_start + 60.0 * args.minutes
    show = not args.no_progress
    root = folders.style_root(args.data or js.mocap_dir() / "100style")
    try:
        styles, new_styles = folders.split_styles(root, args.new_styles)
        unknown = [m for m in args.models if m not in ORDER]
        if unknown:
            raise folders.PipelineError(f"unknown model(s) {', '.join(unknown)}; Table 2 has {', '.join(ORDER)}")
    except folders.PipelineError as e:
        raise SystemExit(f"error: {e}") from None
    gaits = clips.GAITS_100STYLE if (root / "Frame_Cuts.csv").is_file() else None
    data = pipeline.build_data(root, styles, new_styles, gaits=gaits, cache=args.cache,
                               max_seconds=args.max_seconds, progress=show)
    tune_new = pipeline.MODEL in args.models and args.finetune_steps > 0
    jobs = len(args.models) + int(tune_new)
    lines = [f"base styles: {', '.join(data.base.styles)}; new styles: {', '.join(data.new.styles)}; "
             f"{int((data.base.split == 0).sum()):,} training rows; budget {args.minutes:g} min for the whole run "
             f"(data ready after {(time.perf_counter() - t_start) / 60:.1f} min), split evenly over the {jobs} jobs "
             f"left as each starts; at most {args.max_epochs} epochs, early stop when validation has flattened", ""]
    print("\n".join(lines), flush=True)

    def after_each(name: str, done: pipeline.ModelRuns) -> None:
        print(report.model_line(name, done), flush=True)
        partial = lines + report.budget_table(done.runs, done.logs) + [""] + report.models_table(data.base.styles,
                                                                                                 done.results)
        (args.out / "results.md").write_text("\n".join(partial) + "\n\n(partial: the run goes on)\n")
        report.curves_figure(done.logs, args.out / "curves.png")

    configs = {name: pipeline.model_config(data.base, name, hidden=args.hidden,
                                           generator_hidden=args.generator_hidden, filters=args.filters)
               for name in args.models}
    budget = pipeline.SharedBudget(deadline, jobs_after=int(tune_new), max_epochs=args.max_epochs)
    runs, logs, results = pipeline.train_models(data, configs, args.out, budget, progress=show,
                                                after_each=after_each)
    lines += report.budget_table(runs, logs)
    lines += ["", "Test rows, dropout off: mean over styles, then per style MSE / BLL:", ""]
    lines += report.models_table(data.base.styles, results)
    lines += ["", *report.ordering_lines(results)]
    curves = report.curves_figure(logs, args.out / "curves.png",
                                    title=f"Validation MSE, {len(data.base.styles)} styles of "
                                          f"{'the shared 100STYLE sample' if args.data is None else root.name}, "
                                          f"{args.minutes:g}-minute budget")
    files = [curves]
    if tune_new:
        model = runs[pipeline.MODEL].model
        share = max(0.0, deadline - time.perf_counter())
        log = logs[pipeline.MODEL]
        steps_per_epoch = pipeline.steps_per_epoch(model.data)
        step_s = float(log["seconds"][-1]) / steps_per_epoch
        pairs = len(data.new.styles) * len(args.rates)
        steps = int(np.clip(0.8 * share / (SWEEP_STEP_COST * pairs * step_s), 1, args.finetune_steps))
        print(f"fine-tuning: {share / 60:.1f} min left, {step_s:.2f} s per LPN-FiLM training step -> {steps} steps "
              f"per (style, rate)", flush=True)
        result = finetune.generator_sweep(model, data, rates=args.rates, steps=steps, progress=show)
        lines += ["", report.finetune_summary(result), "", *report.finetune_table(result)]
        files += [*finetune.write_finetune(result, args.out).values(),
                  report.film_figure(model, result, args.out / "figure11.png")]
    lines += ["", "wrote " + ", ".join(map(str, files)),
              f"whole run: {(time.perf_counter() - t_start) / 60:.1f} min (budget {args.minutes:g} min)"]
    print("\n".join(lines[2:]))
    (args.out / "results.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
