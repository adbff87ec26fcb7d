"""``jaxstyle sweep``: few-shot styles x dropout rates in one compiled sweep
(:func:`jaxstyle.mason2018.pipeline.run_sweep`)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxstyle.cli.args import (
    add_common,
    add_distributed_args,
    add_joint_map_arg,
    add_sweep_args,
    check_positive,
    finite,
    joint_map,
)
from jaxstyle.cli.common import CLIError, Run, elapsed, machine, progress, written

NAME = "sweep"
HELP = "fine-tune new few-shot styles x dropout rates in one compiled sweep"
DOC = """\
Learn new styles from a few seconds of motion (Mason et al. 2018 section 7): for every few-shot
set (one clip of --seconds per held-out style and gait, or your --clip files) and every dropout
rate, a fresh CP adapter is fine-tuned on the frozen base of RUN/base, all pairs in ONE jit(vmap)
program; each is validated on held-out frames and driven closed-loop, and a rate is chosen per
set. Writes RUN/sweep: results.csv, heatmap.png, chosen_rates.json, adapters/<set>/. An earlier
sweep's sets are kept (a set swept again is updated) unless --replace.
"""


def add_arguments(p) -> None:
    p.add_argument("--sets", nargs="+", help="held-out styles of the data to learn (default: the styles the base "
                                             "was not trained on)")
    p.add_argument("--gaits", nargs="+", help="gaits of the few-shot clips (default: the base's)")
    p.add_argument("--clip", type=Path, nargs="+", help="your own BVH clips (the base's skeleton), one new style "
                                                        "per file named by its stem; replaces --sets")
    p.add_argument("--clip-range", type=finite, nargs=2, metavar=("START", "END"), help="seconds of each --clip")
    p.add_argument("--asymmetric", action="store_true", help="do not mirror the --clip files")
    p.add_argument("--replace", action="store_true",
                   help="start RUN/sweep over: drop the sets of earlier sweeps (default: keep them beside the new)")
    add_joint_map_arg(p)  # default: the base's
    add_distributed_args(p)
    add_common(p)
    add_sweep_args(p, epochs=100)


def sweep_and_report(run: Run, args, base, specs):
    """Run the sweep into RUN/sweep and print its table; returns the result, report paths and shots."""
    from jaxstyle.mason2018 import fewshot, pipeline

    t0 = time.perf_counter()
    config = fewshot.SweepConfig(rates=tuple(args.rates), epochs=args.sweep_epochs,
                                 adapter_dropout_only=args.adapter_dropout_only)
    sweep = pipeline.run_sweep(base, specs, config, cache=run.dir / "cache" if run.writer else None,
                               progress=progress(args))
    paths = (pipeline.write_sweep(sweep, run.dir / "sweep", replace=getattr(args, "replace", False)) if run.writer
             else {})
    result, shots = sweep.result, sweep.shots
    pairs = len(result.styles) * len(result.rates)
    run.say(f"sweep: {len(result.styles)} sets x {len(result.rates)} rates = {pairs} adapters, {args.sweep_epochs} "
            f"epochs each, in one compiled program: {result.seconds['sweep']:.1f} s; checks "
            f"{result.seconds['selection']:.1f} s; {elapsed(t0)} in all")
    for line in pipeline.sweep_table(result):
        run.say(line)
    return result, paths, shots


def run(args, run: Run) -> None:
    from jaxstyle.data import folders
    from jaxstyle.mason2018 import base_model, pipeline

    check_positive(args, "seconds", "sweep_epochs")
    user_map = joint_map(args)
    base = base_model.load_base(run.dir / "base", cache=run.dir / "cache" if run.writer else None,
                              progress=progress(args))
    root = Path(base.settings.data)
    jmap = user_map or base.settings.joint_map
    if args.clip:
        specs = folders.user_clip_specs(args.clip, not args.asymmetric,
                                        tuple(args.clip_range) if args.clip_range else None, jmap)
    else:
        sets = args.sets or [s for s in folders.available_styles(root) if s not in base.settings.styles]
        if not sets:
            raise CLIError(f"the base was trained on every style of {root}: name few-shot --sets or give --clip files")
        folders.split_styles(root, sets, base.settings.styles)  # checks the names
        specs = pipeline.fewshot_specs(root, sets, args.seconds, args.gaits or base.settings.gaits, jmap)
        if not specs:
            gaits = args.gaits or base.settings.gaits or ["(all)"]
            raise CLIError(f"no clip of {', '.join(sets)} with the gaits {', '.join(gaits)}")
    run.say(f"sweep on {machine()}: base {run.dir / 'base'}")
    _, report, _ = sweep_and_report(run, args, base, specs)
    written(run, "written", list(report.values()))
