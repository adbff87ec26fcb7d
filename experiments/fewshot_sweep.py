"""Few-shot sweep on 100STYLE styles the base model never saw (Mason et al. 2018, section 7).

    python experiments/fewshot_sweep.py [--seconds 10] [--rates 0.3 0.5 0.7] [--epochs 100] [--base-epochs 20]
                                        [--adapter-dropout-only] [--matmul-dtype bfloat16]
                                        [--base runs/fewshot/base] [--out runs/fewshot/sweep]
                                        [--clip my_walk.bvh [--clip ...]] [--clip-range START END] [--asymmetric]

The pipeline of ``jaxstyle sweep`` (:mod:`jaxstyle.mason2018.pipeline`) with the paper's settings:

1. Base: a PFNN with CP adapters trained on the shared 100STYLE styles Angry, Chicken, Drunk,
   InTheDark and Neutral (all gaits, mirrored; batch 16 + 16 mirrored frames of one style, Adam
   1e-4, dropout 0.3), once into ``--base`` (re-running resumes or reuses it).
2. Few-shot sets: from each held-out style (Aeroplane, Elated, Rushed) and each of its locomotion
   gaits, ONE clip of ``--seconds`` seconds plus its mirror for symmetric styles, normalised with
   the base statistics.
3. One compiled sweep fine-tunes a fresh CP adapter for every (set, rate); each pair is validated
   on the held-out last cycle and driven closed-loop along a turning path, and a rate is chosen
   per set. Written to ``--out``: ``results.csv``, ``heatmap.png``, ``chosen_rates.json``,
   ``sweep.json`` and ``adapters/<set>/``.

Your own style: ``--clip FILE.bvh`` (repeatable) replaces the held-out sets, one new style per
file named by its stem (100STYLE's skeleton, any frame rate). The whole file is used, or the
seconds ``--clip-range START END`` (the rows need 1 s of trajectory either side); each is
mirrored unless ``--asymmetric``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jaxstyle as js
from jaxstyle.data import datasets, folders
from jaxstyle.mason2018 import base_model, pipeline
from jaxstyle.train.scan import DEFAULT_RATES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0, help="length of each few-shot clip")
    parser.add_argument("--rates", type=float, nargs="+", default=list(DEFAULT_RATES), help="dropout rates")
    parser.add_argument("--epochs", type=int, default=100, help="fine-tuning epochs per pair")
    parser.add_argument("--base-epochs", type=int, default=20)
    parser.add_argument("--adapter-dropout-only", action="store_true", help="faster mode (see SweepConfig)")
    parser.add_argument("--matmul-dtype", default="float32", choices=["float32", "bfloat16"],
                        help="precision of the frozen layers' products (see SweepConfig)")
    parser.add_argument("--base", type=Path, default=Path("runs/fewshot/base"), help="base run folder")
    parser.add_argument("--out", type=Path, default=Path("runs/fewshot/sweep"), help="sweep report and adapters")
    parser.add_argument("--cache", type=Path, default=Path("runs/cache"), help="cached rows")
    parser.add_argument("--clip", type=Path, action="append", default=[], help="your own BVH clip (repeatable)")
    parser.add_argument("--clip-range", type=float, nargs=2, metavar=("START", "END"), help="seconds of each --clip")
    parser.add_argument("--asymmetric", action="store_true", help="do not mirror the --clip files")
    args = parser.parse_args()
    try:  # the user's clips are checked before the base is trained
        user = folders.user_clip_specs(args.clip, not args.asymmetric, args.clip_range and tuple(args.clip_range))
    except folders.PipelineError as e:
        raise SystemExit(f"error: {e}") from None
    mocap = js.mocap_dir()
    t0 = time.perf_counter()
    base = base_model.train_base(base_model.paper_base_settings(mocap, args.base_epochs), args.base, cache=args.cache)
    print(f"base ready in {time.perf_counter() - t0:.0f} s (this call)")
    specs = user or pipeline.fewshot_specs(mocap / "100style", folders.PAPER_FEWSHOT, args.seconds,
                                           folders.LOCOMOTION_GAITS)
    print(f"\nfew-shot sets of {'your clips' if user else f'{args.seconds:g} s'}; rates {args.rates}; "
          f"{args.epochs} epochs")
    sweep = pipeline.run_sweep(
        base, specs, js.SweepConfig(rates=tuple(args.rates), epochs=args.epochs,
                                    adapter_dropout_only=args.adapter_dropout_only, matmul_dtype=args.matmul_dtype),
        skeleton=datasets.load_clip(specs[0], fps=60.0) if user else None,
        cache=args.cache)
    result, paths = sweep.result, pipeline.write_sweep(sweep, args.out)
    pairs = len(result.styles) * len(result.rates)
    print(f"\nsweep: {result.seconds['sweep']:.1f} s for {pairs} pairs ({result.seconds['sweep'] / pairs:.2f} s per "
          f"pair, compile included); validation + closed-loop checks {result.seconds['selection']:.1f} s\n")
    print("\n".join(pipeline.sweep_table(result)))
    print("\nclosed-loop check of the chosen rates (5 s turning path at 45 deg/s, the set's own speed):")
    print("\n".join(pipeline.check_table(result)))
    print("\nwritten: " + ", ".join(str(p) for p in paths.values()))


if __name__ == "__main__":
    main()
