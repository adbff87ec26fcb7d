"""``jaxstyle synthesize``: base and few-shot styles along paths (:func:`jaxstyle.output.synthesis.synthesize`),
with the 2018 PFNN (:func:`jaxstyle.mason2018.pipeline.characters`) or a trained 2022 style model
(:mod:`jaxstyle.mason2022.synthesis`)."""

from __future__ import annotations

import time
from pathlib import Path

from jaxstyle.cli.args import add_common, add_synth_args, check_positive, check_synthesis, finite
from jaxstyle.cli.common import CLIError, Run, elapsed, progress, written

NAME = "synthesize"
HELP = "drive base and few-shot styles along paths: GIF, BVH, quality"
MODELS = ("pfnn", "lpn-film", "lpn-onehot", "lpn-resad", "mann-film", "pfnn-film", "pfnn-onehot", "pfnn-resad")
DOC = """\
Drive characters along named paths, all in one batched, jitted rollout; write <path>.gif (styles
side by side), bvh/<style>_<path>.bvh and .npz, and quality.csv (foot skating, bone error, path
error, jitter, beside real clips of each style).

--model pfnn (the default, Mason et al. 2018): base styles and few-shot styles (the sweep's chosen
adapters) of RUN/base and RUN/sweep, written to RUN/synthesis.

--model lpn-film (Mason, Starke & Komura 2022; or another trained Table 2 model: lpn-onehot,
lpn-resad, mann-film, pfnn-film, pfnn-onehot, pfnn-resad): the model trained by `jaxstyle lpn`
into RUN/lpn (or --model-dir), its training styles (--base-styles; their FiLM vectors) and the new
styles its FiLM generator was fine-tuned on (--sets), written to RUN/synthesis/<model>.
--blend-weights W W [W] adds a 2- or 3-way blend of the first characters (FiLM vectors
interpolated, the paper's section 4.4). The PFNN-backbone models run at a global phase the
controller carries and advances (jaxstyle.control.lpn_controller).
"""


def add_arguments(p) -> None:
    p.add_argument("--model", choices=MODELS, default="pfnn",
                   help="pfnn: the 2018 base + few-shot adapters; lpn-film etc.: a trained 2022 model")
    p.add_argument("--model-dir", type=Path, help="2022 models: the trained model's folder (default RUN/lpn)")
    p.add_argument("--base-styles", nargs="+",
                   help="base (training) styles to show (default: the first; the first two for a 2022 model)")
    p.add_argument("--sets", nargs="+", help="few-shot sets to show (default: the sweep's walking sets, up to 3); "
                                             "2022 models: fine-tuned new styles (default: all, up to 3)")
    p.add_argument("--blend", action="store_true",
                   help="add a 50/50 blend of the first two few-shot sets (2022 models: of the first two styles)")
    p.add_argument("--blend-weights", type=finite, nargs="+", metavar="W",
                   help="2022 models: add a blend of the first 2 or 3 styles shown with these weights (summing to 1)")
    add_common(p)
    add_synth_args(p, paths=("circle", "zigzag"), seconds=8.0)


def synthesis_options(args, **kwargs):
    """The :class:`jaxstyle.output.synthesis.SynthesisOptions` of the command's flags (``--paths``,
    ``--synth-seconds``, ``--speed``, ``--foot-lock``, ``--mp4``, ``--every``)."""
    from jaxstyle.output.synthesis import SynthesisOptions

    return SynthesisOptions(path_names=tuple(args.paths), seconds=args.synth_seconds, speed=args.speed,
                            foot_lock=args.foot_lock, mp4=args.mp4, every=args.every, progress=progress(args),
                            **kwargs)


def synthesize_and_report(run: Run, args, base, shots, chosen, base_styles, sets, blend=False):
    """Synthesise into RUN/synthesis and print the rollout's speed and the quality table."""
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.output import synthesis

    t0 = time.perf_counter()
    chars = pipeline.characters(base, run.dir / "sweep", shots, chosen, base_styles=base_styles, fewshot_sets=sets,
                                blend=blend, allow_failed=args.allow_failed)
    result = synthesis.synthesize(base.character_model(), chars, base.skeleton, run.dir / "synthesis",
                                  synthesis_options(args, contact_sheet=True))
    run.say(f"synthesis: {result.summary(len(chars), len(args.paths))}; with GIF and BVH writing "
            f"{elapsed(t0)}")
    for line in synthesis.quality_table(result.rows):
        run.say(line)
    return result


def blend_weights(args) -> list[float] | None:
    """The 2022 blend's weights: ``--blend-weights``, or 50/50 with ``--blend``, else ``None``."""
    if args.blend_weights is not None:
        if not 2 <= len(args.blend_weights) <= 3:
            raise CLIError(f"--blend-weights: give 2 or 3 weights, got {len(args.blend_weights)}")
        return list(args.blend_weights)
    return [0.5, 0.5] if args.blend else None


def synthesize_lpn_and_report(run: Run, args, loaded, base_styles, sets, out: Path, blend=None):
    """Synthesise a loaded 2022 model's characters (and a blend of the first 2-3 with weights
    ``blend``) into ``out``; print the rollout's speed and the same quality table as the 2018 path."""
    from jaxstyle.mason2022 import synthesis as synthesis2022
    from jaxstyle.output import synthesis

    t0 = time.perf_counter()
    chars = synthesis2022.characters(loaded, styles=base_styles, new_styles=sets, blend=blend,
                                     allow_failed=args.allow_failed)
    result = synthesis.synthesize(loaded.character_model(), chars, loaded.data.skeleton, out,
                                  synthesis_options(args, contact_sheet=True))
    run.say(f"synthesis with {loaded.model.name} ({loaded.epoch_text()}, {loaded.directory}): "
            f"{result.summary(len(chars), len(args.paths))}; with GIF and BVH writing "
            f"{elapsed(t0)}")
    for line in synthesis.quality_table(result.rows):
        run.say(line)
    return result


def default_new_styles(loaded, limit: int = 3) -> list[str]:
    """The fine-tuned new styles of a loaded 2022 model's folder (``chosen_rates.json``), up to ``limit``."""
    import json

    path = loaded.directory / "chosen_rates.json"
    if loaded.model.config.modulation != "film" or loaded.data.new is None or not path.is_file():
        return []
    return list(json.loads(path.read_text()))[:limit]


def run_lpn(args, run: Run) -> None:
    from jaxstyle.mason2022 import synthesis as synthesis2022

    if args.blend_weights is not None and args.blend:
        raise CLIError("give --blend (50/50) or --blend-weights, not both")
    directory = args.model_dir or run.dir / "lpn"
    loaded = synthesis2022.load_model(directory, cache=run.dir / "cache", progress=progress(args))
    loaded = loaded._replace(phase_floor=args.phase_floor, foot_smooth=args.foot_smooth,
                              body_smooth=args.body_smooth)
    kind = synthesis2022.model_key(loaded.model.name) if loaded.model.name in synthesis2022.MODELS.values() else "?"
    if kind != args.model:
        raise CLIError(f"--model {args.model}: {directory} holds {loaded.model.name} ({kind}); "
                       f"give --model {kind} or the folder of a {args.model} model with --model-dir")
    styles = args.base_styles or list(loaded.model.data.styles[:2])
    sets = args.sets if args.sets is not None else default_new_styles(loaded)
    result = synthesize_lpn_and_report(run, args, loaded, styles, sets, run.dir / "synthesis" / args.model,
                                       blend=blend_weights(args))
    written(run, "written", [f for f in result.files if f.suffix != ".npz"])


def run(args, run: Run) -> None:
    check_positive(args, "synth_seconds", "every", "speed")
    check_synthesis(args)
    if args.model != "pfnn":
        return run_lpn(args, run)
    from jaxstyle.mason2018 import base_model, pipeline

    if args.blend_weights is not None or args.model_dir is not None:
        raise CLIError("--blend-weights and --model-dir are for the 2022 models (--model lpn-film ...); the 2018 "
                       "blend is --blend (50/50 of the first two few-shot sets)")
    base = base_model.load_base(run.dir / "base", cache=run.dir / "cache", progress=progress(args))
    chosen, shots = pipeline.load_sweep(run.dir / "sweep", base, cache=run.dir / "cache")
    sets = args.sets if args.sets is not None else pipeline.default_sets(chosen)
    base_styles = args.base_styles or list(base.dataset.styles[:1])
    result = synthesize_and_report(run, args, base, shots, chosen, base_styles, sets, blend=args.blend)
    written(run, "written", [f for f in result.files if f.suffix != ".npz"])
