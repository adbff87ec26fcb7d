"""``jaxstyle synthesize``: base and few-shot styles along paths (:func:`jaxstyle.mason2018.pipeline.synthesize`)."""

from __future__ import annotations

import time

from jaxstyle.cli.common import Run, add_common, add_synth_args, check_positive, elapsed, progress, written

NAME = "synthesize"
HELP = "drive base and few-shot styles along paths: GIF, BVH, quality"
DOC = """\
Drive characters in base styles and few-shot styles (the sweep's chosen adapters) along named
paths, all in one batched, jitted rollout; write RUN/synthesis/<path>.gif (styles side by side),
bvh/<style>_<path>.bvh and .npz, and quality.csv (foot skating, bone error, path error, beside
real clips of each style).
"""


def add_arguments(p) -> None:
    p.add_argument("--base-styles", nargs="+", help="base styles to show (default: the first)")
    p.add_argument("--sets", nargs="+", help="few-shot sets to show (default: the sweep's walking sets, up to 3)")
    p.add_argument("--blend", action="store_true", help="add a 50/50 blend of the first two few-shot sets")
    add_common(p)
    add_synth_args(p, paths=("circle", "zigzag"), seconds=8.0)


def synthesize_and_report(run: Run, args, base, shots, chosen, base_styles, sets, blend=False):
    """Synthesise into RUN/synthesis and print the rollout's speed and the quality table."""
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.output import synthesis

    t0 = time.perf_counter()
    result, chars = pipeline.synthesize(base, run.dir / "sweep", shots, chosen, run.dir / "synthesis",
                                        base_styles=base_styles, fewshot_sets=sets, blend=blend, paths=args.paths,
                                        seconds=args.synth_seconds, speed=args.speed, foot_ik=args.foot_ik,
                                        mp4=args.mp4, every=args.every, progress=progress(args))
    run.say(f"synthesis: {pipeline.rollout_summary(result, len(chars), len(args.paths))}; with GIF and BVH writing "
            f"{elapsed(t0)}")
    for line in synthesis.quality_table(result.rows):
        run.say(line)
    return result


def run(args, run: Run) -> None:
    from jaxstyle.mason2018 import pipeline

    check_positive(args, "synth_seconds", "every")
    base = pipeline.load_base(run.dir / "base", cache=run.dir / "cache", progress=progress(args), log=lambda _: None)
    chosen, shots = pipeline.load_sweep(run.dir / "sweep", base, cache=run.dir / "cache")
    sets = args.sets if args.sets is not None else pipeline.default_sets(chosen)
    base_styles = args.base_styles or list(base.dataset.styles[:1])
    result = synthesize_and_report(run, args, base, shots, chosen, base_styles, sets, blend=args.blend)
    written(run, "written", [f for f in result.files if f.suffix != ".npz"])
