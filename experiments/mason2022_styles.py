"""Train the 2022 style models on the shared 100STYLE clips, test them, and fine-tune LPN-FiLM on
held-out styles (Mason, Starke & Komura 2022, sections 4.3, 5.2.2 and 5.3).

    python experiments/mason2022_styles.py [--epochs 6] [--models "LPN FiLM,LPN One-hot,LPN Resad"]
        [--new-styles Elated,Rushed] [--finetune-steps 150] [--out runs/mason2022]

1. Base data: the shared 100STYLE styles except ``--new-styles`` (mirrored where symmetric),
   contiguous 80/10/10 splits per clip; new styles: their own dataset, normalised with the base's
   statistics (both papers reuse the base normalisation).
2. Each model of ``--models`` (any of Table 2's, the LPN/MANN ones on this data) is trained with
   style-balanced batches (``jaxstyle.mason2022.train.train``; resumes from ``--out/<model>``).
3. Test: normalised MSE and bone-length loss (metres) per style on the test rows, dropout off.
4. New styles: the FiLM generator alone is fine-tuned for every (new style, dropout rate) pair in
   one compiled sweep; the rate with the lowest validation loss is kept; test loss before/after.
5. ``figure11.png``: FiLM parameters of style clips before and after fine-tuning, PCA (the
   paper's Figure 11 uses t-SNE).

Prints Markdown tables and writes them to ``--out/results.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

import jaxstyle as js
from jaxstyle.data import datasets
from jaxstyle.mason2022 import train as train_lpn
from jaxstyle.nn import film_generator as film
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.output import viz


@dataclasses.dataclass(frozen=True)
class Config:
    models: tuple[str, ...] = ("LPN FiLM", "LPN One-hot", "LPN Resad")
    new_styles: tuple[str, ...] = ("Elated", "Rushed")
    epochs: int = 6
    finetune_steps: int = 150
    rates: tuple[float, ...] = (0.1, 0.3, 0.5)
    out: Path = Path("runs/mason2022")
    cache: Path = Path("runs/cache")


def load_data(config: Config):
    root = js.mocap_dir() / "100style"
    all_styles = sorted(p.name for p in root.iterdir() if p.is_dir())
    unknown = sorted(set(config.new_styles) - set(all_styles))
    if unknown:
        raise SystemExit(f"unknown new styles {unknown}; {root} has {', '.join(all_styles)}")
    base_styles = [s for s in all_styles if s not in config.new_styles]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = datasets.build_lpn_dataset(datasets.specs_100style(root, styles=base_styles), cache_dir=config.cache,
                                          skip_short=True, progress=True)
        new = datasets.build_lpn_dataset(datasets.specs_100style(root, styles=config.new_styles),
                                         cache_dir=config.cache, skip_short=True, progress=True)
    skeleton = js.read_bvh(base.specs[0].path)
    return base, new, skeleton


def model_config(name: str, num_styles: int) -> StyleModelConfig:
    paper = StyleModelConfig.paper(name, num_styles)
    if paper.backbone == "pfnn":
        raise SystemExit(f"{name}: the PFNN backbone needs a global phase per row, which the LPN dataset lacks")
    # the data's own layout (342 outputs); the MANN gates on the end effectors' 12 velocities
    return dataclasses.replace(paper, output_size=342)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=",".join(Config.models))
    parser.add_argument("--new-styles", default=",".join(Config.new_styles))
    parser.add_argument("--epochs", type=int, default=Config.epochs)
    parser.add_argument("--finetune-steps", type=int, default=Config.finetune_steps)
    parser.add_argument("--out", type=Path, default=Config.out)
    args = parser.parse_args()
    config = Config(tuple(m.strip() for m in args.models.split(",")), tuple(args.new_styles.split(",")),
                    args.epochs, args.finetune_steps, out=args.out)
    base, new, skeleton = load_data(config)
    lines = []

    def say(text=""):
        print(text, flush=True)
        lines.append(text)

    say(f"base styles: {', '.join(base.styles)}; new styles: {', '.join(new.styles)}; "
        f"{int((base.split == 0).sum())} training rows; {config.epochs} epochs\n")
    results, trained = {}, {}
    for name in config.models:
        mc = model_config(name, len(base.styles))
        data = train_lpn.style_data(base, skeleton, backbone=mc.backbone)
        tc = train_lpn.LPNTrainConfig(model=mc, epochs=config.epochs)
        t0 = time.perf_counter()
        state = train_lpn.train(data, tc, config.out / name.replace(" ", "_"))
        print(f"{name}: trained in {time.perf_counter() - t0:.0f} s (this call)")
        results[name] = train_lpn.evaluate(state["params"], mc, data, "test")
        trained[name] = (mc, state["params"], data)
    say("| model | test MSE (normalised) | test BLL (m) | " + " | ".join(base.styles) + " |")
    say("|---|---|---|" + "---|" * len(base.styles))
    for name, r in results.items():
        per = " | ".join(f"{m:.3f} / {b * 100:.2f} cm" for m, b in zip(r["mse"], r["bll"], strict=True))
        say(f"| {name} | {np.mean(r['mse']):.4f} | {np.mean(r['bll']):.5f} | {per} |")

    if "LPN FiLM" not in trained:
        (config.out / "results.md").write_text("\n".join(lines) + "\n")
        return
    mc, params, data = trained["LPN FiLM"]
    new_data = train_lpn.style_data(new, skeleton, base=base)
    ft = train_lpn.FiLMFinetuneConfig(rates=config.rates, max_steps=config.finetune_steps, epochs=100)
    t0 = time.perf_counter()
    gens, per_step = train_lpn.finetune_film_sweep(params, mc, new_data, ft, chunk_steps=10, progress=True)
    seconds = time.perf_counter() - t0
    say(f"\nfine-tuning the FiLM generator: {len(new.styles)} styles x {len(ft.rates)} rates, "
        f"{per_step.shape[2]} steps each, one compiled sweep: {seconds:.0f} s\n")
    before_test = train_lpn.evaluate(params, mc, new_data, "test")
    before_val = train_lpn.evaluate(params, mc, new_data, "validation")
    say("| new style | rate | validation MSE | test MSE | test BLL (m) |\n|---|---|---|---|---|")
    chosen = {}
    for s, style in enumerate(new.styles):
        say(f"| {style} | before | {before_val['mse'][s]:.4f} | {before_test['mse'][s]:.4f} | "
            f"{before_test['bll'][s]:.5f} |")
        best = None
        for r, rate in enumerate(ft.rates):
            tuned = train_lpn.with_generator(params, gens, s, r)
            val = train_lpn.evaluate(tuned, mc, new_data, "validation", styles=[s])
            test = train_lpn.evaluate(tuned, mc, new_data, "test", styles=[s])
            say(f"| {style} | {rate} | {val['mse'][0]:.4f} | {test['mse'][0]:.4f} | {test['bll'][0]:.5f} |")
            total = val["mse"][0] + val["bll"][0]
            if np.isfinite(total) and (best is None or total < best[0]):
                best = (total, r)
        chosen[style] = best[1] if best else 0
    say("\n(validation rows are used to choose the rate; a style without validation rows keeps the first rate)")

    clips_per_style = 50
    before, after = {}, {}
    gen0 = params["style"]["generator"]
    for s, style in enumerate(base.styles):
        c = data.train_clips[s][:clips_per_style]
        before[style] = after[style] = film.clip_films(gen0, data.clips[c])
    for s, style in enumerate(new.styles):
        c = new_data.train_clips[s][:clips_per_style]
        before[style] = film.clip_films(gen0, new_data.clips[c])
        tuned = train_lpn.with_generator(params, gens, s, chosen[style])["style"]["generator"]
        after[style] = film.clip_films(tuned, new_data.clips[c])
    fig = viz.plot_film_projection({"before fine-tuning": before, "after fine-tuning": after},
                                   new_styles=new.styles, title="FiLM parameters of style clips (PCA)")
    fig.savefig(config.out / "figure11.png", dpi=100)
    say(f"\nwrote {config.out / 'figure11.png'}")
    (config.out / "results.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
