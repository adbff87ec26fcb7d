"""``jaxstyle lpn``: the 2022 LPN-FiLM network trained, tested and fine-tuned on new styles
(:mod:`jaxstyle.mason2022.pipeline`)."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path

from jaxstyle.cli.args import (
    LazyDefault,
    add_common,
    add_distributed_args,
    add_joint_map_arg,
    check_positive,
    finite,
    joint_map,
    non_negative,
)
from jaxstyle.cli.common import DATA_HELP, CLIError, Run, elapsed, machine, progress, written

FINETUNE_RATES = LazyDefault("jaxstyle.train.defaults", "FILM_DEFAULT_RATES")
CHOOSE_EPOCHS = LazyDefault("jaxstyle.train.defaults", "CHOOSE_EPOCHS")  # a module that starts no JAX
NAME = "lpn"
HELP = "train the 2022 LPN-FiLM network, test it, fine-tune it on new styles"
DOC = """\
Mason, Starke & Komura 2022: train the local-phase network with FiLM layers driven by a style-clip
encoder on the training styles of --data (bone-length loss included); take the model from the
epoch, among the last three kept, whose training styles step best in the closed loop (each walks
8 s along a straight line; the epoch with the most styles lifting their feet within 25% of their
captures' rate wins; recorded in RUN/lpn/chosen_epoch.json and loaded from then on; --choose-epoch
0, --average-epochs above 1 and --distributed keep the last epoch, the paper's); report its test
MSE and bone length loss per style, then fine-tune only the FiLM generator on each new style at
every dropout rate in one compiled sweep, report the losses before and after, and choose a rate
per new style (lowest validation loss). Writes RUN/lpn: checkpoints, chosen_epoch.json,
results.md, chosen_rates.json, finetuned_generators.npz and figure11.png. Last, every training
and new style walks 8 s along a straight line with the default runtime and is measured as
experiments/quality.py measures it: the table (also in results.md) names the styles that do not
step, lifting their feet at under half their capture's rate (a pose frozen while the root moves;
the test loss does not show it). --no-style-check skips it.

With --clip FILE.bvh [FILE2.bvh ...] the new styles are your own clips of the training data's
skeleton instead (one new style per file, named by its stem; --clip-range START END keeps those
seconds of each; mirrored unless --asymmetric): the trained model of RUN/lpn is reloaded (give
the flags it was trained with; it is trained first if it is not there), its FiLM generator alone
is fine-tuned on every clip at every --rates in one compiled sweep, each pair is validated on the
clip's held-out frames and driven closed-loop by the 2022 controller, and a rate is chosen per
clip (lowest validation loss among the pairs that pass the check). Writes RUN/lpn: chosen_rates.json
(with the check), finetuned_generators.npz, generators/<style>.npz (the chosen generator),
clips.json and results.md; `jaxstyle synthesize` can then drive the clip styles.
"""


def add_arguments(p) -> None:
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    p.add_argument("--styles", nargs="+", help="training styles (default: all but --new-styles)")
    p.add_argument("--new-styles", nargs="+", help="styles to fine-tune on (default: as the few-shot styles)")
    p.add_argument("--gaits", nargs="+", help="gait codes (default: the locomotion gaits)")
    p.add_argument("--max-seconds", type=finite, help="use only the first seconds of each clip")
    p.add_argument("--epochs", type=int, default=6, help="training epochs (paper: 90)")
    p.add_argument("--seed", type=int, default=0,
                   help="training seed: initial weights, dropout and batch order (recorded in RUN/lpn/config.json)")
    p.add_argument("--hidden", type=int, default=512, help="hidden units (paper: 512)")
    p.add_argument("--generator-hidden", type=int, default=2048, help="FiLM generator's dense units (paper: 2048)")
    p.add_argument("--filters", type=int, default=256, help="FiLM generator's convolution filters (paper: 256)")
    p.add_argument("--finetune-steps", type=int, default=150, help="fine-tuning steps per (style, rate); 0: none")
    p.add_argument("--rates", type=finite, nargs="+", default=FINETUNE_RATES, help="fine-tuning dropout rates")
    p.add_argument("--choose-rate", choices=("walk", "validation"), default="walk",
                   help="how each held-out new style's rate is chosen: walk (default; not in the paper): every "
                        "(style, rate) walks 8 s along a straight line and the lowest validation loss among the rates "
                        "lifting their feet within 25%% of the capture's rate wins; validation: the lowest validation "
                        "loss alone (docs/mason2022.md, 'New styles that step')")
    p.add_argument("--clip", type=Path, nargs="+", help="your own BVH clips (the training data's skeleton), one new "
                                                        "style per file named by its stem; replaces --new-styles")
    p.add_argument("--clip-range", type=finite, nargs=2, metavar=("START", "END"), help="seconds of each --clip")
    p.add_argument("--asymmetric", action="store_true", help="do not mirror the --clip files")
    p.add_argument("--devices", help="train data-parallel over 'all' devices or that many (default: one)")
    p.add_argument("--batch-size", type=int, default=32,
                   help="minibatch (paper: 32); Adam's rate scales by sqrt(batch / 32) from 1e-4")
    p.add_argument("--bf16", action="store_true", help="bfloat16 products, float32 accumulation and weights")
    p.add_argument("--input-noise", type=non_negative, default=0.0,
                   help="std of Gaussian noise on the normalised inputs in training (not in the paper; 0: none)")
    p.add_argument("--feedback-noise", type=non_negative, default=0.0,
                   help="std of Gaussian noise on the normalised joint features only, the inputs the closed loop "
                        "feeds back (not in the paper; 0: none; docs/mason2022.md, 'The closed loop: why it froze')")
    p.add_argument("--rollout-steps", type=int, default=0,
                   help="rollout training: each row starts a window of 1 + N frames fed the network's own outputs "
                        "(not in the paper; 0: none; docs/mason2022.md, 'The closed loop: why it froze')")
    p.add_argument("--contact-loss", type=non_negative, default=0.0,
                   help="weight of the loss on planted feet moving, in metres per frame (not in the paper; 0: none; "
                        "docs/mason2022.md, 'Feet that slide')")
    p.add_argument("--average-epochs", type=int, default=0,
                   help="the model is the mean of the last N epochs' weights (not in the paper; 0 or 1: the last "
                        "epoch's; docs/mason2022.md, 'Averaged weights')")
    p.add_argument("--choose-epoch", type=int, default=CHOOSE_EPOCHS,
                   help="the model is the epoch, of the last N, whose training styles step best along the closing "
                        "check's straight line (not in the paper; 0 or 1: the last epoch's, the paper's; off with "
                        "--average-epochs above 1 and --distributed; docs/mason2022.md, 'Choosing the epoch')")
    p.add_argument("--no-style-check", action="store_true",
                   help="skip the closing check: every style walked 8 s along a straight line and measured "
                        "(lifted steps, feet on the floor, skating, style distance against its capture)")
    add_joint_map_arg(p)
    add_distributed_args(p)
    add_common(p)


def run(args, run: Run) -> None:
    if run.writer:
        _sync(args)  # the others have copied the run's model before this process changes it
        _run(args, run, run.dir / "lpn", run.dir / "cache")
        return
    # another process of a --distributed run: the same work, its files in a folder of its own
    # (removed at the end), starting from a copy of the run's model so that every process
    # resumes the same state; process 0 writes the run folder
    with tempfile.TemporaryDirectory(prefix="jaxstyle-process-") as scratch:
        out = Path(scratch) / "lpn"
        if (run.dir / "lpn").is_dir():
            shutil.copytree(run.dir / "lpn", out)
        _sync(args)
        _run(args, run, out, None)


def _sync(args) -> None:
    if args.distributed:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices("jaxstyle lpn: every process has the run's model")


def _run(args, run: Run, out: Path, cache: Path | None) -> None:
    from jaxstyle.data import folders
    from jaxstyle.mason2022 import finetune, pipeline, report

    check_positive(args, "epochs", "hidden", "generator_hidden", "filters")
    if args.finetune_steps < 0:
        raise CLIError(f"--finetune-steps must be >= 0, got {args.finetune_steps}")
    if args.choose_epoch < 0:
        raise CLIError(f"--choose-epoch must be >= 0, got {args.choose_epoch}")
    if args.clip and args.finetune_steps == 0:
        raise CLIError("--clip needs fine-tuning steps: --finetune-steps must be > 0")
    if args.clip_range and not args.clip:
        raise CLIError("--clip-range needs --clip files")
    root = folders.style_root(args.data)
    # with --clip and --styles, no style of the folder is held out (the clips are the new styles)
    held_out = () if args.clip and args.styles and not args.new_styles else args.new_styles
    styles, new_styles = folders.split_styles(root, held_out, args.styles)
    if args.clip:
        new_styles = ()
    new_text = ", ".join(new_styles) or "your --clip files"
    run.say(f"lpn on {machine()}: training styles {', '.join(styles)}; new styles {new_text}")
    data = pipeline.build_data(root, styles, new_styles, gaits=args.gaits, max_seconds=args.max_seconds,
                               cache=cache, progress=progress(args), joint_map=joint_map(args))
    if args.clip:
        data = finetune.user_clip_data(data, args.clip, mirror=not args.asymmetric,
                                       seconds=tuple(args.clip_range) if args.clip_range else None,
                                       joint_map=joint_map(args), cache=cache, progress=progress(args))
        run.say(f"new styles from your clips: {', '.join(data.new.styles)} ({len(data.new.specs)} clip(s), mirrors "
                f"included, {int((data.new.split == 0).sum()):,} training rows)")
    config = pipeline.model_config(data.base, hidden=args.hidden, generator_hidden=args.generator_hidden,
                                   filters=args.filters)
    t0 = time.perf_counter()
    wanted = args.choose_epoch > 1 and args.average_epochs <= 1
    choose = wanted and not args.distributed
    model = pipeline.train_model(data, config, out, epochs=args.epochs, progress=progress(args), seed=args.seed,
                                 chosen=choose, **_speed_options(args))
    run.say(f"LPN-FiLM ({args.hidden} hidden, {args.epochs} epochs, {int((data.base.split == 0).sum()):,} training "
            f"rows) ready in {elapsed(t0)}: {run.dir / 'lpn'}")
    chosen, files, epoch = [], [out, out / "results.md"], args.epochs
    if wanted and args.distributed:
        run.say("the last epoch's weights: the epoch is chosen only in a one-process run (a process of several "
                "does not read earlier epochs back)")
    elif choose:
        model, chosen, epoch = choose_epoch_and_say(run, model, data, out, args.choose_epoch)
        files += [out / pipeline.CHOSEN_EPOCH_FILE] if chosen else []
    lines = []
    for line in report.losses_table(model.data.styles, pipeline.model_losses(model)):
        run.say(line)
    if args.clip:
        result, checked, paths = finetune.finetune_clips(model, data, out, rates=args.rates,
                                                         steps=args.finetune_steps, progress=progress(args))
        lines = [*report.check_table(result, checked), "", *report.finetune_table(result, checked=True)]
        for line in ["", report.finetune_summary(result) + "; then a closed-loop check of every pair", *lines]:
            run.say(line)
        run.say("chosen rates: " + ", ".join(f"{s} {result.chosen_rate(s):g}" for s in result.styles))
        files += list(paths.values())
    elif args.finetune_steps > 0:
        result, summary = finetune_new_styles(model, data, out, epoch, args.epochs, rates=args.rates,
                                              steps=args.finetune_steps, choose_rate=args.choose_rate,
                                              progress=progress(args))
        lines = report.finetune_table(result)
        for line in ["", summary, *lines]:
            run.say(line)
        run.say("chosen rates: " + ", ".join(f"{s} {result.chosen_rate(s):g}" for s in result.styles))
        files += list(finetune.write_finetune(result, out).values())
        files.append(report.film_figure(model, result, out / "figure11.png"))
    if not args.no_style_check:  # every process of a --distributed run, as the sweep; process 0 says it
        lines += ["", *_style_check(run, args, model, data, out, epoch)]
    if chosen:
        lines = [*chosen, "", *lines]
    (out / "results.md").write_text("\n".join(lines) + "\n")
    written(run, "written", files)


def finetune_new_styles(model, data, out: Path, epoch: int, trained_epochs: int, *, rates, steps: int,
                        choose_rate: str, progress: bool):
    """The FiLM generator fine-tuned on the held-out new styles at every rate in one compiled sweep
    (:func:`jaxstyle.mason2022.finetune.generator_sweep`), each style's rate chosen by walking every
    pair (``choose_rate="walk"``, :func:`jaxstyle.mason2022.synthesis.choose_stepping_rates`) or by
    the validation loss alone; returned with the line that says what was done (``jaxstyle lpn`` and
    ``jaxstyle demo --model lpn-film``)."""
    from jaxstyle.mason2022 import finetune, report
    from jaxstyle.mason2022 import synthesis as synthesis2022

    result = finetune.generator_sweep(model, data, rates=rates, steps=steps, progress=progress)
    summary = report.finetune_summary(result)
    if choose_rate == "walk":
        t0 = time.perf_counter()
        loaded = synthesis2022.Loaded(model, data, out, epoch, trained_epochs=trained_epochs)
        result = synthesis2022.choose_stepping_rates(loaded, result)
        summary += (f"; then every pair walked {synthesis2022.STYLE_CHECK_SECONDS:g} s along a straight line "
                    f"({elapsed(t0)})")
    return result, summary


def choose_epoch_and_say(run: Run, model, data, out: Path, epochs: int):
    """The model of the epoch, of the last ``epochs`` kept in ``out``, whose training styles step
    best in the closed loop (:func:`jaxstyle.mason2022.synthesis.choose_epoch`): said, and returned
    with the markdown lines that say it and the epoch (``jaxstyle lpn`` and ``jaxstyle demo --model
    lpn-film``)."""
    from jaxstyle.mason2022 import report
    from jaxstyle.mason2022 import synthesis as synthesis2022

    t0 = time.perf_counter()
    choice = synthesis2022.choose_epoch(model, data, out, epochs=epochs)
    if not choice.ratios:  # a single epoch kept: nothing to choose
        return choice.model, [], choice.epoch
    lines = [f"epoch chosen by the closed loop: {choice.epoch} of {choice.trained_epochs} ({elapsed(t0)}; the "
             f"epoch whose training styles lift their feet within 25% of their captures' rate most often, "
             f"{synthesis2022.STYLE_CHECK_SECONDS:g} s along a straight line; lifted steps / capture's per epoch)",
             "", *report.epoch_choice_table(choice)]
    for line in ["", *lines]:
        run.say(line)
    return choice.model, lines, choice.epoch


def _style_check(run: Run, args, model, data, out: Path, epoch: int) -> list[str]:
    """The closing check (:func:`jaxstyle.mason2022.synthesis.style_check`) of the training styles
    and the new styles just fine-tuned: said and returned as markdown lines."""
    from jaxstyle.mason2022 import report
    from jaxstyle.mason2022 import synthesis as synthesis2022

    t0 = time.perf_counter()
    new = list(data.new.styles) if data.new is not None and args.finetune_steps > 0 else []
    loaded = synthesis2022.Loaded(model, data, out, epoch, trained_epochs=args.epochs)
    rows = synthesis2022.style_check(loaded, list(model.data.styles), new)
    lines = [f"closed loop of every style: {synthesis2022.STYLE_CHECK_SECONDS:g} s along a straight line at its "
             f"own speed, default runtime ({elapsed(t0)})", "", *report.style_check_table(rows)]
    for line in ["", *lines]:
        run.say(line)
    return lines


def _speed_options(args) -> dict:
    """``train_model`` options of --devices, --distributed, --batch-size, --bf16, --input-noise,
    --feedback-noise, --rollout-steps, --contact-loss and --average-epochs (defaults: the paper's batch 32 and rate
    1e-4, float32, one device, no noise, no rollout training, no contact loss, the last epoch's weights)."""
    from jaxstyle.mason2022 import train as train_lpn
    from jaxstyle.train import shard

    check_positive(args, "batch_size")
    devices = None
    if args.devices is not None:
        if args.devices != "all" and not args.devices.isdigit():
            raise CLIError(f"--devices must be 'all' or a count, got {args.devices!r}")
        devices = args.devices if args.devices == "all" else int(args.devices)
        try:
            shard.check_batch(shard.data_mesh(devices), args.batch_size)
        except ValueError as e:
            raise CLIError(f"--devices {args.devices}: {e}") from None
    if devices is None and args.distributed:
        devices = "all"  # every process's devices
    if args.rollout_steps < 0:
        raise CLIError(f"--rollout-steps must be >= 0, got {args.rollout_steps}")
    if args.average_epochs < 0:
        raise CLIError(f"--average-epochs must be >= 0, got {args.average_epochs}")
    options = {"devices": devices, "compute_dtype": "bfloat16" if args.bf16 else "float32"}
    if args.input_noise:
        options["input_noise"] = args.input_noise
    if args.feedback_noise:
        options["feedback_noise"] = args.feedback_noise
    if args.rollout_steps:
        options["rollout_steps"] = args.rollout_steps
    if args.contact_loss:
        options["contact_loss_weight"] = args.contact_loss
    if args.average_epochs > 1:
        options["average_epochs"] = args.average_epochs
    if args.batch_size != train_lpn.PAPER_BATCH:
        scaled = train_lpn.with_batch_size(train_lpn.LPNTrainConfig(), args.batch_size)
        options.update(batch_size=scaled.batch_size, learning_rate=scaled.learning_rate)
    return options
