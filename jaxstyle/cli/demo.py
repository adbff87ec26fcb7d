"""``jaxstyle demo``: data, base, few-shot sweep and synthesis end to end (:mod:`jaxstyle.mason2018.pipeline`)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Sequence

from jaxstyle.cli.common import (
    DATA_HELP,
    DEMO_RUN,
    CLIError,
    Run,
    add_base_args,
    add_common,
    add_sweep_args,
    add_synth_args,
    check_positive,
    elapsed,
    machine,
    progress,
    written,
)
from jaxstyle.cli.sweep import sweep_and_report
from jaxstyle.cli.synthesize import synthesize_and_report
from jaxstyle.cli.train_base import base_settings

NAME = "demo"
HELP = "train, sweep and synthesise end to end on procedural styles or --data (~5 min, 2 CPU cores)"
DOC = """\
One command from nothing to a stylised animation (Mason et al. 2018 end to end):

1. data: without --data, procedural stylised locomotion (jaxstyle.data.procedural: Neutral, Crouched,
   Bouncy, ArmSwing, Limping, Proud; walks and runs with turns and speed changes, exact phases
   and contacts) is written to RUN/data; with --data, that style folder is used;
2. a small base PFNN (hidden 256, CP adapters of rank 16) is trained on the base styles;
3. a few-shot sweep learns each held-out style (Limping, Proud; or the paper's Aeroplane,
   Elated and Rushed on 100STYLE) from one clip of --seconds, at every dropout rate, in one
   compiled program, and chooses a rate per style (RUN/sweep: results.csv, heatmap.png);
4. base and few-shot styles walk a path (RUN/synthesis: a GIF, BVH files, quality.csv).

About 5 minutes on a 2-core CPU with the defaults. Re-running resumes or reuses the base.
"""
DEMO_MAX_BASE_STYLES = 8


def add_arguments(p) -> None:
    p.add_argument("--data", type=Path, help=DATA_HELP + "; used instead of the procedural styles, e.g. "
                                               "../shared/mocap")
    add_common(p, DEMO_RUN)
    add_base_args(p, hidden=256, epochs=12, rank=16)
    add_sweep_args(p, epochs=40)
    add_synth_args(p, paths=("circle",), seconds=8.0)
    p.add_argument("--data-seconds", type=float, default=24.0, help="seconds of each procedural clip")


def demo_base_styles(base_styles: Sequence[str]) -> list[str]:
    """The demo's base styles on real data: all of them up to :data:`DEMO_MAX_BASE_STYLES`, else the
    paper's sweep base styles present (or the first ones), so the whole 100STYLE takes minutes."""
    from jaxstyle.data.folders import PAPER_BASE

    if len(base_styles) <= DEMO_MAX_BASE_STYLES:
        return list(base_styles)
    paper = [s for s in PAPER_BASE if s in base_styles]
    return (paper or list(base_styles))[:DEMO_MAX_BASE_STYLES]


def _data_root(args, run: Run) -> Path:
    """The style folder: procedural styles written to RUN/data, or --data (defaults adjusted)."""
    from jaxstyle.data import procedural
    from jaxstyle.mason2018 import pipeline

    if args.data is None:
        root = run.dir / "data"
        if not (root / "procedural.json").is_file():
            t0 = time.perf_counter()
            procedural.write_dataset(root, seconds=args.data_seconds, progress=progress(args))
            run.say(f"data: procedural styles {', '.join(procedural.STYLES)} x gaits "
                    f"{', '.join(procedural.GAITS)}, {args.data_seconds:g} s each, written to {root} ({elapsed(t0)})")
        else:
            run.say(f"data: procedural styles in {root} (written earlier)")
        if args.gaits is None:
            args.gaits = list(procedural.GAITS)
        return root
    root = pipeline.style_root(args.data)
    run.say(f"data: {root}")
    if args.max_seconds is None:
        args.max_seconds = 20.0  # keeps the demo short on large folders; train-base uses everything
    if args.styles is None:
        all_base, _ = pipeline.split_styles(root, args.fewshot_styles)
        args.styles = demo_base_styles(all_base)
        if len(args.styles) < len(all_base):
            run.say(f"the demo trains on {len(args.styles)} of the {len(all_base)} base styles "
                    f"({', '.join(args.styles)}); `jaxstyle train-base` uses them all")
    return root


def run(args, run: Run) -> None:
    from jaxstyle.mason2018 import pipeline

    t_all = time.perf_counter()
    check_positive(args, "seconds", "synth_seconds", "data_seconds")
    run.say(f"jaxstyle demo on {machine()}")
    root = _data_root(args, run)
    run.save_settings(vars(args))  # with the defaults the data folder implied
    settings, held_out = base_settings(args, root)
    t0 = time.perf_counter()
    base = pipeline.train_base(settings, run.dir / "base", cache=run.dir / "cache", progress=progress(args),
                               log=run.say)
    run.say(f"base ready ({elapsed(t0)})")
    specs = pipeline.fewshot_specs(root, held_out, args.seconds, settings.gaits)
    if not specs:
        raise CLIError(f"the few-shot styles {', '.join(held_out)} have no clip of the gaits "
                       f"{', '.join(settings.gaits or ['(all)'])} in {root}")
    _, report, shots = sweep_and_report(run, args, base, specs)
    chosen = json.loads(report["chosen"].read_text())
    base_styles = [s for s in ("Neutral", "Crouched") if s in base.dataset.styles] or list(base.dataset.styles[:1])
    synth = synthesize_and_report(run, args, base, shots, chosen, base_styles, pipeline.default_sets(chosen))
    run.say("")
    written(run, "written", [run.dir / "base", report["csv"], report["heatmap"], report["chosen"]]
            + [f for f in synth.files if f.suffix in (".gif", ".mp4", ".csv", ".png")]
            + [run.dir / "synthesis" / "bvh" / f"({sum(f.suffix == '.bvh' for f in synth.files)} BVH files)"])
    run.say(f"config and log: {run.dir / 'config.json'}, {run.dir / 'log.txt'}")
    run.say(f"demo finished in {elapsed(t_all)}")
