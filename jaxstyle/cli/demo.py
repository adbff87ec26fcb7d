"""``jaxstyle demo``: data, base, few-shot sweep and synthesis end to end (:mod:`jaxstyle.mason2018.pipeline`)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Sequence

from jaxstyle.cli.args import (
    add_base_args,
    add_common,
    add_sweep_args,
    add_synth_args,
    check_positive,
    check_synthesis,
    finite,
    joint_map,
)
from jaxstyle.cli.common import DATA_HELP, DEMO_RUN, CLIError, Run, elapsed, machine, progress, written
from jaxstyle.cli.lpn import choose_epoch_and_say, finetune_new_styles
from jaxstyle.cli.sweep import sweep_and_report
from jaxstyle.cli.synthesize import synthesize_and_report, synthesize_lpn_and_report
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
4. base and few-shot styles walk a path (RUN/synthesis: a GIF, BVH files, quality.csv);
5. the same characters walk the quality benchmark's target paths (straight, circle, zigzag and
   stop_and_go, --synth-seconds each, at each style's own speed): the table of
   experiments/quality.py (jaxstyle.output.quality: skating of the network's joints, of the
   exported BVH and after contact IK, bone error, path error, heading, time to stop, jitter,
   beside each style's capture) and the benchmark's path and stop targets (final path error <= 0.3 m
   on straight, circle and zigzag; stopped within 0.5 s) marked pass or FAIL
   (RUN/synthesis/quality_targets.csv; --no-quality skips it).

About 5 minutes on a 2-core CPU with the defaults. Re-running resumes or reuses the base.

--model lpn-film runs Mason, Starke & Komura 2022 instead: LPN rows of the base styles, LPN-FiLM
trained with a smaller preset than the paper's (see --hidden, --filters, --generator-hidden,
--lpn-epochs, --learning-rate; RUN/lpn; its last epoch, or with --choose-epoch N the epoch of the
last N whose training styles step best, as `jaxstyle lpn`), its FiLM generator fine-tuned on the
held-out styles (--finetune-steps; each style's rate the one, of those whose walk steps, with the
lowest validation loss: --choose-rate), then base styles, a fine-tuned style and a FiLM blend along the paths
(RUN/synthesis/lpn-film: GIF, BVH files, quality.csv), and the same quality table and targets
(RUN/synthesis/lpn-film/quality_targets.csv). The characters' local phases advance at least
--phase-floor of their capture's rate (0: the paper's runtime, whose loop can stall).
"""
DEMO_MAX_BASE_STYLES = 8
DEMO_MODELS = ("pfnn", "lpn-film", "lpn-onehot", "lpn-resad", "mann-film")
DEMO_FINETUNE_RATES = (0.1, 0.3)
"""The demo's FiLM fine-tuning rates (``jaxstyle lpn`` sweeps :data:`jaxstyle.train.defaults.FILM_DEFAULT_RATES`)."""


def add_arguments(p) -> None:
    p.add_argument("--data", type=Path, help=DATA_HELP + "; used instead of the procedural styles, e.g. "
                                               "../shared/mocap")
    add_common(p, DEMO_RUN)
    add_base_args(p, hidden=256, epochs=12, rank=16)
    add_sweep_args(p, epochs=40)
    add_synth_args(p, paths=("circle",), seconds=8.0)
    p.add_argument("--data-seconds", type=finite, default=24.0, help="seconds of each procedural clip")
    p.add_argument("--no-quality", action="store_true",
                   help="skip the quality table on the benchmark's target paths (step 5)")
    p.add_argument("--model", choices=DEMO_MODELS, default="pfnn",
                   help="pfnn: the 2018 pipeline; lpn-film (or another LPN/MANN model of the 2022 paper's Table 2): "
                        "the 2022 pipeline")
    g = p.add_argument_group("2022 models (--model lpn-film ...)")
    g.add_argument("--lpn-epochs", type=int, default=4,
                   help="training epochs of the 2022 model (paper: 90; after 2 the closed loop of most styles still "
                        "stalls; at 16 the demo's FiLM generator loses its styles, docs/synthesis.md)")
    g.add_argument("--choose-epoch", type=int, default=0,
                   help="the model is the epoch, of the last N, whose training styles step best along a straight "
                        "line, as `jaxstyle lpn` (not in the paper; default 0: the last epoch's, the paper's: "
                        "measured on the demo at 4 epochs it made as many runs worse as better; docs/synthesis.md)")
    g.add_argument("--lpn-seed", type=int, default=0,
                   help="training seed of the 2022 model: initial weights, dropout and batch order")
    g.add_argument("--learning-rate", type=finite, default=1e-3,
                   help="Adam learning rate of the 2022 model (demo: 1e-3 for its few epochs; paper and "
                        "`jaxstyle lpn`: 1e-4)")
    g.add_argument("--generator-hidden", type=int, default=512,
                   help="FiLM generator's dense units (demo preset; paper and `jaxstyle lpn`: 2048)")
    g.add_argument("--filters", type=int, default=32,
                   help="FiLM generator's convolution filters (demo preset; paper and `jaxstyle lpn`: 256)")
    g.add_argument("--finetune-steps", type=int, default=40,
                   help="FiLM fine-tuning steps per (new style, rate); 0: no new styles")
    g.add_argument("--choose-rate", choices=("walk", "validation"), default="walk",
                   help="how each new style's fine-tuning rate is chosen: walk (default, as `jaxstyle lpn`; not in "
                        "the paper): the lowest validation loss among the rates whose 8-s walk along a straight line "
                        "lifts its feet within 25%% of the capture's rate; validation: the lowest validation loss "
                        "(docs/mason2022.md, 'New styles that step')")
    g.add_argument("--blend-weights", type=finite, nargs="+", default=[0.5, 0.5], metavar="W",
                   help="weights of the blend of the first 2 or 3 styles shown (FiLM vectors interpolated)")


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
    from jaxstyle.data import folders, procedural

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
    root = folders.style_root(args.data)
    run.say(f"data: {root}")
    if args.max_seconds is None:
        args.max_seconds = 20.0  # keeps the demo short on large folders; train-base uses everything
    if args.styles is None:
        all_base, _ = folders.split_styles(root, args.fewshot_styles)
        args.styles = demo_base_styles(all_base)
        if len(args.styles) < len(all_base):
            run.say(f"the demo trains on {len(args.styles)} of the {len(all_base)} base styles "
                    f"({', '.join(args.styles)}); `jaxstyle train-base` uses them all")
    return root


def report_quality(run: Run, args, measure, out: Path) -> Path:
    """Step 5: ``measure(path_names, seconds)`` (:func:`jaxstyle.output.quality.run` on the demo's
    characters of either model) along the benchmark's target
    paths; print the benchmark's table (:func:`jaxstyle.output.report.table`, as
    ``experiments/quality.py`` prints it), the foot-locking targets and the path and stop targets
    with pass/FAIL marks (:func:`jaxstyle.output.report.target_marks`); write the rows to ``out`` (CSV)."""
    from jaxstyle.output import quality, report

    t0 = time.perf_counter()
    rows, _ = measure(quality.TARGET_PATHS, args.synth_seconds)
    run.say("")
    run.say(f"quality on the benchmark's target paths ({', '.join(quality.TARGET_PATHS)}; {args.synth_seconds:g} s "
            f"each at each style's own speed; {elapsed(t0)}), the measures of experiments/quality.py (skating of the "
            "network's joints / the exported BVH / the BVH after foot locking, stepping after locking, beside each "
            "style's capture):")
    checks = report.targets(rows)
    for line in ["", *report.table(rows), "", *report.target_marks(checks, report.LOCK_TARGETS), "",
                 *report.target_marks(checks)]:
        run.say(line)
    out.parent.mkdir(parents=True, exist_ok=True)
    return report.write_csv(rows, out)


def run_lpn(args, run: Run, root: Path, t_all: float) -> None:
    """The 2022 pipeline end to end: LPN rows, a style model (the demo's smaller FiLM generator),
    FiLM fine-tuning on the held-out styles, characters (and a FiLM blend) along the paths."""
    from jaxstyle.data import folders
    from jaxstyle.mason2022 import finetune, pipeline, report
    from jaxstyle.mason2022 import synthesis as synthesis2022

    check_positive(args, "lpn_epochs", "hidden", "generator_hidden", "filters", "learning_rate")
    name = synthesis2022.MODELS[args.model]
    styles, new_styles = folders.split_styles(root, args.fewshot_styles, args.styles)
    t0 = time.perf_counter()
    data = pipeline.build_data(root, styles, new_styles, gaits=args.gaits, max_seconds=args.max_seconds,
                               cache=run.dir / "cache", progress=progress(args), joint_map=joint_map(args))
    run.say(f"LPN data: {len(data.base.styles)} training styles ({', '.join(data.base.styles)}), "
            f"{int((data.base.split == 0).sum()):,} training rows, {len(data.base.clips)} style clips; new styles "
            f"{', '.join(data.new.styles) if data.new is not None else 'none'} ({elapsed(t0)})")
    config = pipeline.model_config(data.base, name, hidden=args.hidden, generator_hidden=args.generator_hidden,
                                   filters=args.filters)
    if config.modulation == "film":
        run.say(f"{name}: the demo's smaller preset: {args.hidden} hidden units, a FiLM generator of "
                f"{args.filters} filters and {args.generator_hidden} dense units (the paper's, and `jaxstyle lpn`'s "
                f"default: 512, 256 and 2048); {args.lpn_epochs} epochs at learning rate {args.learning_rate:g} "
                "(paper: 90 at 1e-4)")
    else:
        run.say(f"{name}: the demo's smaller preset: {args.hidden} hidden units (paper: 512); {args.lpn_epochs} "
                f"epochs at learning rate {args.learning_rate:g} (paper: 90 at 1e-4)")
    t0 = time.perf_counter()
    model = pipeline.train_model(data, config, run.dir / "lpn", name=name, epochs=args.lpn_epochs,
                                 progress=progress(args), learning_rate=args.learning_rate, seed=args.lpn_seed,
                                 chosen=args.choose_epoch > 1)
    run.say(f"{name} ready ({elapsed(t0)})")
    files, epoch = [run.dir / "lpn"], args.lpn_epochs
    if args.choose_epoch > 1:
        model, chosen, epoch = choose_epoch_and_say(run, model, data, run.dir / "lpn", args.choose_epoch)
        files += [run.dir / "lpn" / pipeline.CHOSEN_EPOCH_FILE] if chosen else []
    for line in report.losses_table(model.data.styles, pipeline.model_losses(model)):
        run.say(line)
    sets = []
    if config.modulation == "film" and args.finetune_steps > 0 and data.new is not None:
        result, summary = finetune_new_styles(model, data, run.dir / "lpn", epoch, args.lpn_epochs,
                                              rates=DEMO_FINETUNE_RATES, steps=args.finetune_steps,
                                              choose_rate=args.choose_rate, progress=progress(args))
        for line in ["", summary, *report.finetune_table(result)]:
            run.say(line)
        files += list(finetune.write_finetune(result, run.dir / "lpn").values())
        sets = list(result.styles[:1])
    loaded = synthesis2022.Loaded(model, data, run.dir / "lpn", epoch, phase_floor=args.phase_floor,
                                  foot_smooth=args.foot_smooth, body_smooth=args.body_smooth,
                                  trained_epochs=args.lpn_epochs)
    base_styles = [s for s in ("Neutral", "Crouched") if s in model.data.styles] or list(model.data.styles[:2])
    blend = list(args.blend_weights) if args.blend_weights else None
    if blend is not None and len(blend) == 3 and len(base_styles) + len(sets) < 3:
        base_styles = list(model.data.styles[:3])
    synth = synthesize_lpn_and_report(run, args, loaded, base_styles, sets, run.dir / "synthesis" / args.model,
                                      blend=blend)
    if not args.no_quality:
        files.append(report_quality(run, args, lambda names, seconds: lpn_quality(loaded, base_styles, sets, names,
                                                                                  seconds),
                                    run.dir / "synthesis" / args.model / "quality_targets.csv"))
    run.say("")
    bvh = run.dir / "synthesis" / args.model / "bvh" / f"({sum(f.suffix == '.bvh' for f in synth.files)} BVH files)"
    written(run, "written", files + [f for f in synth.files if f.suffix in (".gif", ".mp4", ".csv", ".png")] + [bvh])
    run.say(f"config and log: {run.dir / 'config.json'}, {run.dir / 'log.txt'}")
    run.say(f"demo finished in {elapsed(t_all)}")


def run(args, run: Run) -> None:
    from jaxstyle.mason2018 import base_model, pipeline

    t_all = time.perf_counter()
    check_positive(args, "seconds", "synth_seconds", "data_seconds", "speed")
    check_synthesis(args)
    if args.choose_epoch < 0:
        raise CLIError(f"--choose-epoch must be >= 0, got {args.choose_epoch}")
    run.say(f"jaxstyle demo on {machine()}" + ("" if args.model == "pfnn" else f" (--model {args.model})"))
    root = _data_root(args, run)
    run.save_settings(vars(args))  # with the defaults the data folder implied
    if args.model != "pfnn":
        return run_lpn(args, run, root, t_all)
    settings, held_out = base_settings(args, root)
    t0 = time.perf_counter()
    base = base_model.train_base(settings, run.dir / "base", cache=run.dir / "cache", progress=progress(args),
                               log=run.say)
    run.say(f"base ready ({elapsed(t0)})")
    specs = pipeline.fewshot_specs(root, held_out, args.seconds, settings.gaits, settings.joint_map)
    if not specs:
        raise CLIError(f"the few-shot styles {', '.join(held_out)} have no clip of the gaits "
                       f"{', '.join(settings.gaits or ['(all)'])} in {root}")
    _, report, shots = sweep_and_report(run, args, base, specs)
    chosen = json.loads(report["chosen"].read_text())
    base_styles = [s for s in ("Neutral", "Crouched") if s in base.dataset.styles] or list(base.dataset.styles[:1])
    sets = pipeline.default_sets(chosen)
    synth = synthesize_and_report(run, args, base, shots, chosen, base_styles, sets)
    files = [run.dir / "base", report["csv"], report["heatmap"], report["chosen"]]
    if not args.no_quality:
        files.append(report_quality(run, args, lambda names, seconds: pfnn_quality(
            base, run.dir / "sweep", shots, chosen, base_styles, sets, names, seconds, args.allow_failed),
            run.dir / "synthesis" / "quality_targets.csv"))
    run.say("")
    written(run, "written", files + [f for f in synth.files if f.suffix in (".gif", ".mp4", ".csv", ".png")]
            + [run.dir / "synthesis" / "bvh" / f"({sum(f.suffix == '.bvh' for f in synth.files)} BVH files)"])
    run.say(f"config and log: {run.dir / 'config.json'}, {run.dir / 'log.txt'}")
    run.say(f"demo finished in {elapsed(t_all)}")


def pfnn_quality(base, sweep_dir: Path, shots, chosen: dict, base_styles: Sequence[str], sets: Sequence[str],
                 path_names: Sequence[str], seconds: float, allow_failed: bool = False):
    """The demo's 2018 characters (base styles, few-shot sets) measured by :func:`jaxstyle.output.quality.run`."""
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.output import quality

    chars = pipeline.characters(base, sweep_dir, shots, chosen, base_styles=base_styles, fewshot_sets=sets,
                                allow_failed=allow_failed)
    subjects = [quality.subject(c, "base" if i < len(base_styles) else "few-shot") for i, c in enumerate(chars)]
    return quality.run(base.character_model(), subjects, base.skeleton, path_names=path_names, seconds=seconds)


def lpn_quality(loaded, base_styles: Sequence[str], sets: Sequence[str], path_names: Sequence[str], seconds: float):
    """A loaded 2022 model's characters (training styles, fine-tuned new styles; not the blend, which
    has no capture of its own) measured by :func:`jaxstyle.mason2022.synthesis.measure_quality`."""
    from jaxstyle.mason2022 import synthesis as synthesis2022

    return synthesis2022.measure_quality(loaded, base_styles, sets, path_names=path_names, seconds=seconds)
