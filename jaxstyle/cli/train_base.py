"""``jaxstyle train-base``: the 2018 base PFNN with one CP adapter per style
(:func:`jaxstyle.mason2018.base_model.train_base`)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxstyle.cli.args import add_base_args, add_common, joint_map
from jaxstyle.cli.common import DATA_HELP, Run, elapsed, machine, progress

NAME = "train-base"
HELP = "train the 2018 base PFNN with one CP adapter per style"
DOC = """\
Train the base PFNN of Mason et al. 2018 (phase-functioned network with one CP residual adapter
per style, style-balanced half-mirrored batches, Adam 1e-4, dropout 0.3) on the base styles of
--data into RUN/base (checkpoints each epoch; re-running resumes; config, log.csv and the
normalisation statistics beside them). The styles left out are the later few-shot styles.
"""


def add_arguments(p) -> None:
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    add_common(p)
    add_base_args(p, hidden=512, epochs=20, rank=30)


def base_settings(args, root: Path):
    """The :class:`~jaxstyle.mason2018.base_model.BaseSettings` of the arguments, and the held-out styles."""
    from jaxstyle.data import folders
    from jaxstyle.mason2018 import base_model

    base_styles, held_out = folders.split_styles(root, args.fewshot_styles, args.styles)
    gaits = tuple(args.gaits) if args.gaits else None
    settings = base_model.BaseSettings(str(root), base_styles, gaits, hidden=args.hidden, rank=args.rank,
                                     epochs=args.base_epochs, max_seconds=args.max_seconds,
                                     joint_map=joint_map(args))
    return settings, held_out


def run(args, run: Run) -> None:
    from jaxstyle.data import folders
    from jaxstyle.mason2018 import base_model

    root = folders.style_root(args.data)
    settings, held_out = base_settings(args, root)
    run.say(f"train-base on {machine()}; held out for few-shot: {', '.join(held_out)}")
    t0 = time.perf_counter()
    base = base_model.train_base(settings, run.dir / "base", cache=run.dir / "cache", progress=progress(args),
                               log=run.say)
    run.say(f"base ready in {elapsed(t0)}: {run.dir / 'base'} (per-epoch validation losses in log.csv there, "
            f"{len(base.dataset.styles)} style adapters)")
