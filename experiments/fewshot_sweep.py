"""Few-shot sweep on 100STYLE styles the base model never saw (Mason et al. 2018, section 7).

    python experiments/fewshot_sweep.py [--seconds 10] [--rates 0.3 0.5 0.7] [--epochs 100] [--base-epochs 20]
                                        [--adapter-dropout-only] [--matmul-dtype bfloat16]
                                        [--base runs/fewshot/base] [--out runs/fewshot/sweep]
                                        [--clip my_walk.bvh [--clip ...]] [--clip-range START END]
                                        [--asymmetric]

1. Base: a PFNN with CP adapters trained on the shared 100STYLE styles Angry, Chicken, Drunk,
   InTheDark and Neutral (all gaits, mirrored; 2018 settings: batch 16 + 16 mirrored frames of
   one style, Adam 1e-4, dropout 0.3). Trained once into ``--base`` (re-running resumes or
   reuses it); its normalisation statistics are saved beside it.
2. Few-shot sets: from each held-out style (Aeroplane, Elated, Rushed) and each of its locomotion
   gaits in the sample, ONE clip of ``--seconds`` seconds (from the 100STYLE frame cut), plus its
   mirror for symmetric styles (as the paper's code: asymmetric ones are not mirrored),
   normalised with the base statistics; the mirrored rows are shuffled in with the originals.
3. One compiled sweep fine-tunes a fresh CP adapter for every (set, rate), then each pair is
   validated on the held-out last cycle and driven closed-loop along a turning path, and a rate
   is chosen per set (:mod:`jaxstyle.mason2018.selection`). Written to ``--out``: ``results.csv``,
   ``heatmap.png``, ``chosen_rates.json`` and ``adapters/<set>/`` checkpoints.

Your own style: ``--clip FILE.bvh`` (repeatable) replaces the held-out 100STYLE sets with your
clips, one new style per file named by its stem (it needs the base's skeleton, i.e. 100STYLE's,
at any frame rate; it is resampled to 60 fps). The whole file is used, or the seconds
``--clip-range START END`` of each (the PFNN rows need 1 s of trajectory either side, so a
range of S seconds gives S - 2 s of rows). Each is mirrored unless ``--asymmetric`` says the
style is not left-right symmetric (a limp, say).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
from pathlib import Path

import jax
import numpy as np

import jaxstyle as js
from jaxstyle.data import datasets
from jaxstyle.data.datasets import ClipSpec
from jaxstyle.mason2018 import fewshot, pipeline, selection

BASE_STYLES = ("Angry", "Chicken", "Drunk", "InTheDark", "Neutral")
FEWSHOT_STYLES = ("Aeroplane", "Elated", "Rushed")
LOCOMOTION_GAITS = ("BR", "BW", "FR", "FW", "SR", "SW")  # not idle (ID) or transitions (TR)


@dataclasses.dataclass(frozen=True)
class Config:
    seconds: float = 10.0
    rates: tuple[float, ...] = (0.3, 0.5, 0.7)
    epochs: int = 100
    base_epochs: int = 20
    base: Path = Path("runs/fewshot/base")
    out: Path = Path("runs/fewshot/sweep")
    cache: Path = Path("runs/cache")
    adapter_dropout_only: bool = False
    matmul_dtype: str = "float32"
    clips: tuple[Path, ...] = ()
    clip_range: tuple[float, float] | None = None
    asymmetric: bool = False


def fewshot_specs(root: Path, seconds: float) -> list[ClipSpec]:
    """One clip of ``seconds`` (plus the trajectory window) per held-out style and gait, and its
    mirror when the style is symmetric (all three are)."""
    return pipeline.fewshot_specs(root, FEWSHOT_STYLES, seconds, LOCOMOTION_GAITS)


def base_model(mocap: Path, config: Config) -> pipeline.Base:
    """The base (:func:`jaxstyle.mason2018.pipeline.train_base`: trained into ``config.base``, or resumed, or
    loaded) on every gait of the base styles, at the paper's sizes."""
    settings = pipeline.BaseSettings(str(mocap / "100style"), BASE_STYLES, datasets.GAITS_100STYLE,
                                     epochs=config.base_epochs)
    t0 = time.perf_counter()
    base = pipeline.train_base(settings, config.base, cache=config.cache)
    print(f"base ready in {time.perf_counter() - t0:.0f} s (this call)")
    return base


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=Config.seconds, help="length of each few-shot clip")
    parser.add_argument("--rates", type=float, nargs="+", default=list(Config.rates), help="dropout rates to sweep")
    parser.add_argument("--epochs", type=int, default=Config.epochs, help="fine-tuning epochs per pair")
    parser.add_argument("--base-epochs", type=int, default=Config.base_epochs)
    parser.add_argument("--adapter-dropout-only", action="store_true",
                        help="the faster mode: dropout on the adapter path only (see SweepConfig)")
    parser.add_argument("--matmul-dtype", default=Config.matmul_dtype, choices=["float32", "bfloat16"],
                        help="precision of the frozen layers' products (see SweepConfig)")
    parser.add_argument("--base", type=Path, default=Config.base, help="base model run folder (trained if empty)")
    parser.add_argument("--out", type=Path, default=Config.out, help="folder for the sweep's report and adapters")
    parser.add_argument("--clip", type=Path, action="append", default=[],
                        help="your own BVH clip (100STYLE skeleton) to learn as a new style named by its file stem; "
                             "repeat for several; replaces the held-out 100STYLE sets")
    parser.add_argument("--clip-range", type=float, nargs=2, metavar=("START", "END"),
                        help="use these seconds of each --clip file (default: the whole file)")
    parser.add_argument("--asymmetric", action="store_true", help="do not mirror the --clip files")
    args = parser.parse_args()
    config = Config(seconds=args.seconds, rates=tuple(args.rates), epochs=args.epochs, base_epochs=args.base_epochs,
                    base=args.base, out=args.out, adapter_dropout_only=args.adapter_dropout_only,
                    matmul_dtype=args.matmul_dtype, clips=tuple(args.clip),
                    clip_range=tuple(args.clip_range) if args.clip_range else None, asymmetric=args.asymmetric)
    # the user's clips are checked before the base is trained
    try:
        user_specs = pipeline.user_clip_specs(config.clips, not config.asymmetric, config.clip_range)
    except pipeline.PipelineError as e:
        raise SystemExit(f"error: {e}") from None
    mocap = js.mocap_dir()
    print(f"machine: {platform.processor() or platform.machine()}, jax {jax.__version__} on "
          f"{jax.devices()[0].platform} x {jax.device_count()}")
    base = base_model(mocap, config)
    params, normalisers, model = base.params, base.normalisers, base.model

    specs = user_specs or fewshot_specs(mocap / "100style", config.seconds)
    fewshot_set = datasets.build_pfnn_dataset(specs, cache_dir=config.cache)
    skeleton = base.skeleton if not user_specs else datasets.load_clip(specs[0], fps=60.0)
    sweep_config = fewshot.SweepConfig(model=model, epochs=config.epochs, rates=config.rates,
                                       adapter_dropout_only=config.adapter_dropout_only,
                                       matmul_dtype=config.matmul_dtype)
    length = f"{config.seconds:g} s each"
    if user_specs:
        length = "whole files" if config.clip_range is None else "{:g}-{:g} s of each file".format(*config.clip_range)
    mirrored = "" if user_specs and config.asymmetric else " + mirror"
    print(f"\nfew-shot sets: {len(fewshot_set.styles)} ({', '.join(fewshot_set.styles)}), {length}{mirrored}; "
          f"rates {config.rates}; {config.epochs} epochs of batch {sweep_config.batch_size}")
    result = selection.fewshot_sweep(params, normalisers, fewshot_set, skeleton, sweep_config)
    paths = selection.write_report(result, config.out, sweep_config)
    pairs = len(result.styles) * len(result.rates)
    print(f"\nsweep: {result.seconds['sweep']:.1f} s for {pairs} pairs ({result.seconds['sweep'] / pairs:.2f} s per "
          f"pair, compile included); validation + closed-loop checks {result.seconds['selection']:.1f} s\n")
    print("| set | train rows | validation rows | " + " | ".join(f"val @ {r:g}" for r in result.rates)
          + " | chosen | check |")
    print("|---|---|---|" + "---|" * len(result.rates) + "---|---|")
    for s, style in enumerate(result.styles):
        cells = []
        for r in range(len(result.rates)):
            mark = "" if result.rollout["passed"][s, r] else " (fails check)"
            cells.append(f"{result.validation_loss[s, r]:.3f}{mark}")
        print(f"| {style} | {result.train_rows[s]} | {result.validation_rows[s]} | " + " | ".join(cells)
              + f" | {result.chosen_rate(style):g} | {'passed' if result.chosen_passed[s] else 'FAILED'} |")
    print("\nclosed-loop check of the chosen rates (5 s turning path at 45 deg/s, the set's own speed):")
    print("| set | bone error (base) | feet on floor (real) | skating m/s (base; real) | distance / requested |")
    print("|---|---|---|---|---|")
    for s, style in enumerate(result.styles):
        r = int(result.chosen[s])
        ro, ref = result.rollout, result.reference
        print(f"| {style} | {100 * ro['bone_error'][s, r]:.1f}% ({100 * ref['base_bone_error'][s]:.1f}%) "
              f"| {ro['contact_fraction'][s, r]:.2f} ({ref['contact_fraction'][s]:.2f}) "
              f"| {ro['skating_m_s'][s, r]:.2f} ({ref['base_skating_m_s'][s]:.2f}; {ref['skating_m_s'][s]:.2f}) "
              f"| {ro['progress'][s, r]:.2f} |")
    print("\nwritten: " + ", ".join(str(p) for p in paths.values()))
    mean = np.nanmean(result.validation_loss, axis=0)
    per_rate = ", ".join(f"{r:g}: {m:.3f}" for r, m in zip(result.rates, mean, strict=True))
    print(f"mean validation loss per rate: {per_rate}")


if __name__ == "__main__":
    main()
