"""``jaxstyle lpn``: the 2022 LPN-FiLM network trained, tested and fine-tuned on new styles
(:mod:`jaxstyle.mason2022.pipeline`)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxstyle.cli.common import (
    DATA_HELP,
    CLIError,
    LazyDefault,
    Run,
    add_common,
    check_positive,
    elapsed,
    machine,
    progress,
    written,
)

FINETUNE_RATES = LazyDefault("jaxstyle.train.defaults", "FILM_DEFAULT_RATES")
NAME = "lpn"
HELP = "train the 2022 LPN-FiLM network, test it, fine-tune it on new styles"
DOC = """\
Mason, Starke & Komura 2022: train the local-phase network with FiLM layers driven by a style-clip
encoder on the training styles of --data (bone-length loss included), report test MSE and bone
length loss per style, then fine-tune only the FiLM generator on each new style at every dropout
rate in one compiled sweep, report the losses before and after, and choose a rate per new style
(lowest validation loss). Writes RUN/lpn: checkpoints, results.md, chosen_rates.json,
finetuned_generators.npz and figure11.png.
"""


def add_arguments(p) -> None:
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    p.add_argument("--styles", nargs="+", help="training styles (default: all but --new-styles)")
    p.add_argument("--new-styles", nargs="+", help="styles to fine-tune on (default: as the few-shot styles)")
    p.add_argument("--gaits", nargs="+", help="gait codes (default: the locomotion gaits)")
    p.add_argument("--max-seconds", type=float, help="use only the first seconds of each clip")
    p.add_argument("--epochs", type=int, default=6, help="training epochs (paper: 90)")
    p.add_argument("--hidden", type=int, default=512, help="hidden units (paper: 512)")
    p.add_argument("--generator-hidden", type=int, default=2048, help="FiLM generator's dense units (paper: 2048)")
    p.add_argument("--filters", type=int, default=256, help="FiLM generator's convolution filters (paper: 256)")
    p.add_argument("--finetune-steps", type=int, default=150, help="fine-tuning steps per (style, rate); 0: none")
    p.add_argument("--rates", type=float, nargs="+", default=FINETUNE_RATES, help="fine-tuning dropout rates")
    add_common(p)


def run(args, run: Run) -> None:
    from jaxstyle.data import folders
    from jaxstyle.mason2022 import pipeline

    check_positive(args, "epochs", "hidden", "generator_hidden", "filters")
    if args.finetune_steps < 0:
        raise CLIError(f"--finetune-steps must be >= 0, got {args.finetune_steps}")
    root = folders.style_root(args.data)
    styles, new_styles = folders.split_styles(root, args.new_styles, args.styles)
    run.say(f"lpn on {machine()}: training styles {', '.join(styles)}; new styles {', '.join(new_styles)}")
    data = pipeline.build_data(root, styles, new_styles, gaits=args.gaits, max_seconds=args.max_seconds,
                               cache=run.dir / "cache", progress=progress(args))
    config = pipeline.model_config(data.base, hidden=args.hidden, generator_hidden=args.generator_hidden,
                                   filters=args.filters)
    t0 = time.perf_counter()
    model = pipeline.train_model(data, config, run.dir / "lpn", epochs=args.epochs, progress=progress(args))
    run.say(f"LPN-FiLM ({args.hidden} hidden, {args.epochs} epochs, {int((data.base.split == 0).sum()):,} training "
            f"rows) ready in {elapsed(t0)}: {run.dir / 'lpn'}")
    for line in pipeline.losses_table(model.data.styles, pipeline.model_losses(model)):
        run.say(line)
    lines, files = [], [run.dir / "lpn", run.dir / "lpn" / "results.md"]
    if args.finetune_steps > 0:
        result = pipeline.finetune_sweep(model, data, rates=args.rates, steps=args.finetune_steps,
                                         progress=progress(args))
        lines = pipeline.finetune_table(result)
        for line in ["", pipeline.finetune_summary(result), *lines]:
            run.say(line)
        run.say("chosen rates: " + ", ".join(f"{s} {result.chosen_rate(s):g}" for s in result.styles))
        files += list(pipeline.write_finetune(result, run.dir / "lpn").values())
        files.append(pipeline.film_figure(model, result, run.dir / "lpn" / "figure11.png"))
    (run.dir / "lpn" / "results.md").write_text("\n".join(lines) + "\n")
    written(run, "written", files)
