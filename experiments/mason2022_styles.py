"""Train the 2022 style models on the shared 100STYLE clips, test them, and fine-tune LPN-FiLM on
held-out styles (Mason, Starke & Komura 2022, sections 4.3, 5.2.2 and 5.3).

    python experiments/mason2022_styles.py [--epochs 6] [--models "LPN FiLM,LPN One-hot,LPN Resad"]
        [--new-styles Elated,Rushed] [--finetune-steps 150] [--out runs/mason2022]

The pipeline of ``jaxstyle lpn`` (:mod:`jaxstyle.mason2022.pipeline`) for several models:

1. Data: the shared 100STYLE styles except ``--new-styles`` (every gait, mirrored where symmetric,
   80/10/10 splits per clip); the new styles normalised with the base's statistics.
2. Each model of ``--models`` (Table 2's LPN and MANN ones) is trained with style-balanced batches
   (resumes from ``--out/<model>``) and tested: normalised MSE and bone-length loss per style.
3. New styles: the FiLM generator of LPN FiLM alone is fine-tuned for every (new style, dropout
   rate) pair in one compiled sweep; the rate with the lowest validation loss is kept.
4. ``figure11.png``: FiLM parameters of style clips before and after fine-tuning, PCA (the
   paper's Figure 11 uses t-SNE); ``chosen_rates.json`` and ``finetuned_generators.npz``.

Prints Markdown tables and writes them to ``--out/results.md``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jaxstyle as js
from jaxstyle.data import datasets, folders
from jaxstyle.mason2022 import pipeline


def names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", type=names, default="LPN FiLM,LPN One-hot,LPN Resad")
    parser.add_argument("--new-styles", type=names, default=",".join(pipeline.PAPER_NEW_STYLES))
    parser.add_argument("--epochs", type=int, default=6)
    parser.add_argument("--finetune-steps", type=int, default=150)
    parser.add_argument("--rates", type=float, nargs="+", default=list(pipeline.FINETUNE_RATES))
    parser.add_argument("--out", type=Path, default=Path("runs/mason2022"))
    parser.add_argument("--cache", type=Path, default=Path("runs/cache"))
    args = parser.parse_args()
    root = folders.style_root(js.mocap_dir() / "100style")
    try:
        styles, new_styles = folders.split_styles(root, args.new_styles)
    except folders.PipelineError as e:
        raise SystemExit(f"error: {e}") from None
    data = pipeline.build_data(root, styles, new_styles, gaits=datasets.GAITS_100STYLE, cache=args.cache,
                               progress=True)
    lines = [f"base styles: {', '.join(data.base.styles)}; new styles: {', '.join(data.new.styles)}; "
             f"{int((data.base.split == 0).sum())} training rows; {args.epochs} epochs", ""]
    print("\n".join(lines), flush=True)
    results, models = {}, {}
    for name in args.models:
        t0 = time.perf_counter()
        config = pipeline.model_config(data.base, name)
        models[name] = pipeline.train_model(data, config, args.out / name.replace(" ", "_"), name=name,
                                            epochs=args.epochs)
        print(f"{name}: trained in {time.perf_counter() - t0:.0f} s (this call)")
        results[name] = pipeline.model_losses(models[name])
    lines += pipeline.models_table(data.base.styles, results)
    if pipeline.MODEL in models and args.finetune_steps > 0:
        model = models[pipeline.MODEL]
        result = pipeline.finetune_sweep(model, data, rates=args.rates, steps=args.finetune_steps)
        lines += ["", pipeline.finetune_summary(result), "", *pipeline.finetune_table(result)]
        files = [*pipeline.write_finetune(result, args.out).values(),
                 pipeline.film_figure(model, result, args.out / "figure11.png")]
        lines += ["", "wrote " + ", ".join(map(str, files))]
    print("\n".join(lines[2:]))
    (args.out / "results.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
