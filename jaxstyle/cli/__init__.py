"""The ``jaxstyle`` command line: the whole pipeline from data to animation, one subcommand per step.

    jaxstyle demo [--data PATH]        # procedural styles (no download) or your data -> GIF, BVH, sweep
    jaxstyle data generate|fetch|prepare
    jaxstyle train-base --data PATH    # Mason et al. 2018 base PFNN with per-style CP adapters
    jaxstyle sweep                     # few-shot styles x dropout rates in one compiled sweep
    jaxstyle lpn --data PATH           # Mason et al. 2022 LPN-FiLM: train, test, fine-tune new styles
    jaxstyle synthesize                # characters along user paths: GIF, BVH, quality figures
    jaxstyle render FILE.bvh ...       # a GIF of any BVH files
    jaxstyle bench                     # fine-tuning sweep against a loop, network speed

Every step that trains or writes results works in a run folder (``--run``, default
``runs/jaxstyle``; the demo's is ``runs/demo``): ``base/``, ``sweep/``, ``synthesis/``, ``lpn/``,
``cache/``, with ``config.json`` (the settings of each command run there) and ``log.txt`` (what
each printed). Settings come from flags or from a TOML file (``--config FILE``; flags win), whose
keys are the flags' long names (``base-epochs = 10``), at top level or in a table named after the
command. Bad arguments and missing files end with a one-line error; ``--debug`` shows the
traceback instead.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import os
import platform
import sys
import time
import tomllib
from pathlib import Path
from typing import Callable, Sequence

DEFAULT_RUN = Path("runs/jaxstyle")
DATA_HELP = ("a style folder: <Style>/<Style>_<GAIT>.bvh files, with 100STYLE's Frame_Cuts.csv or without it (whole "
             "files), or a folder holding 100style/")
DEMO_RUN = Path("runs/demo")
DEMO_MAX_BASE_STYLES = 8
PAPER_BASE_STYLES = ("Angry", "Chicken", "Drunk", "InTheDark", "Neutral")  # experiments/fewshot_sweep.py


class CLIError(Exception):
    """A problem with the user's arguments or files, reported on one line."""


# --- the run folder -----------------------------------------------------------------------------

def _jsonable(value):
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


_UNSAVED = ("handler", "debug", "quiet")


class Run:
    """A run folder: ``say`` prints and appends to ``log.txt``; the command's settings are saved in
    ``config.json`` under the command's name (earlier commands' entries are kept)."""

    def __init__(self, directory: Path, command: str, settings: dict, argv: Sequence[str]):
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.command = command
        self.save_settings(settings)
        self._log = open(self.dir / "log.txt", "a", encoding="utf-8")
        stamp = datetime.datetime.now().isoformat(timespec="seconds")
        self._log.write(f"\n=== {stamp} jaxstyle {' '.join(argv)}\n")
        self._log.flush()

    def save_settings(self, settings: dict) -> None:
        """Write ``settings`` into ``config.json`` under this command's name (atomically)."""
        config_path = self.dir / "config.json"
        config = {}
        if config_path.is_file():
            with contextlib.suppress(json.JSONDecodeError):
                config = json.loads(config_path.read_text())
        config[self.command] = _jsonable({k: v for k, v in settings.items() if k not in _UNSAVED})
        tmp = config_path.with_name("config.json.tmp")
        tmp.write_text(json.dumps(config, indent=2))
        os.replace(tmp, config_path)

    def say(self, text: str = "") -> None:
        print(text, flush=True)
        self._log.write(text + "\n")
        self._log.flush()

    def close(self) -> None:
        self._log.close()


# --- argument parsing ---------------------------------------------------------------------------

class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (and a pointer to ``--help``) instead of the usage block."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _Formatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Raw descriptions; defaults shown unless there is none or the help already says it."""

    def _get_help_string(self, action):
        if action.default in (None, False) or "default" in (action.help or ""):
            return action.help
        return super()._get_help_string(action)


def _common(parser: argparse.ArgumentParser, run_default: Path | None = DEFAULT_RUN) -> None:
    if run_default is not None:
        parser.add_argument("--run", type=Path, default=run_default,
                            help="run folder: models, reports, config.json and log.txt")
    parser.add_argument("--config", type=Path, help="TOML file of settings (keys = long flag names); flags win")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--debug", action="store_true", help="show tracebacks instead of one-line errors")


def _add_base_args(p: argparse.ArgumentParser, *, hidden: int, epochs: int, rank: int) -> None:
    p.add_argument("--styles", nargs="+", help="base (training) styles (default: all but the few-shot ones)")
    p.add_argument("--fewshot-styles", nargs="+",
                   help="styles held out for the few-shot sweep (default: the procedural data's Limping and Proud, "
                        "100STYLE's Aeroplane, Elated and Rushed when present, else the last style)")
    p.add_argument("--gaits", nargs="+", help="100STYLE gait codes to use (default: the locomotion gaits "
                                               "BR BW FR FW SR SW)")
    p.add_argument("--hidden", type=int, default=hidden, help="hidden units of the PFNN (paper: 512)")
    p.add_argument("--rank", type=int, default=rank, help="rank of the CP adapters (paper: 30)")
    p.add_argument("--base-epochs", type=int, default=epochs, help="base training epochs (paper: 25)")
    p.add_argument("--max-seconds", type=float, help="use only the first seconds of each base clip")


def _add_sweep_args(p: argparse.ArgumentParser, *, epochs: int) -> None:
    p.add_argument("--seconds", type=float, default=10.0, help="length of each few-shot clip (paper: a few seconds)")
    p.add_argument("--rates", type=float, nargs="+", default=[0.3, 0.5, 0.7], help="dropout rates to sweep")
    p.add_argument("--sweep-epochs", type=int, default=epochs, help="fine-tuning epochs per (set, rate) (paper: 100)")
    p.add_argument("--adapter-dropout-only", action="store_true",
                   help="faster mode: dropout on the adapter path only (see jaxstyle.mason2018.fewshot.SweepConfig)")


def _add_synth_args(p: argparse.ArgumentParser, *, paths: Sequence[str], seconds: float) -> None:
    from jaxstyle.control.paths import PATHS

    p.add_argument("--paths", nargs="+", default=list(paths), choices=list(PATHS), help="paths to walk")
    p.add_argument("--synth-seconds", type=float, default=seconds, help="length of each synthesised path")
    p.add_argument("--speed", type=float, help="speed of every character, m/s (default: each style's own)")
    p.add_argument("--foot-ik", action="store_true", help="pin the feet in contact in the BVH files")
    p.add_argument("--mp4", action="store_true", help="also write MP4s (needs ffmpeg)")
    p.add_argument("--every", type=int, default=2, help="draw every n-th frame in the animations")


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, argparse.ArgumentParser]]:
    """The parser and, per command name (``"data fetch"`` for nested ones), its sub-parser."""
    from jaxstyle import __version__

    parser = _Parser(prog="jaxstyle", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"jaxstyle {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    subs = {}

    def add(name, help_text, description, handler, parent=sub, key=None):
        p = parent.add_parser(name, help=help_text, description=description, formatter_class=_Formatter)
        p.set_defaults(handler=handler)
        subs[key or name] = p
        return p

    p = add("demo", "train, sweep and synthesise end to end on procedural styles or --data (~5 min, 2 CPU cores)",
            DEMO_DOC, cmd_demo)
    p.add_argument("--data", type=Path, help=DATA_HELP + "; used instead of the procedural styles, e.g. "
                                               "../shared/mocap")
    _common(p, DEMO_RUN)
    _add_base_args(p, hidden=256, epochs=12, rank=16)
    _add_sweep_args(p, epochs=40)
    _add_synth_args(p, paths=("circle",), seconds=8.0)
    p.add_argument("--data-seconds", type=float, default=24.0, help="seconds of each procedural clip")

    data = add("data", "make, download or inspect motion data", "Make, download or inspect motion data.", None)
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", parser_class=_Parser)
    subs["data"] = data
    p = add("generate", "write procedural stylised locomotion in the 100STYLE layout", GENERATE_DOC, cmd_generate,
            data_sub, "data generate")
    p.add_argument("--out", type=Path, default=Path("data/procedural"), help="folder to write")
    p.add_argument("--styles", nargs="+", help="styles (default: all)")
    p.add_argument("--gaits", nargs="+", help="gaits (default: FW FR)")
    p.add_argument("--seconds", type=float, default=24.0, help="seconds per clip")
    p.add_argument("--seed", type=int, default=0)
    _common(p, None)
    p = add("fetch", "download a public dataset (resumable, checksummed) and unpack it", FETCH_DOC, cmd_fetch,
            data_sub, "data fetch")
    p.add_argument("name", help="dataset name, e.g. 100style")
    p.add_argument("--dest", type=Path, default=Path("data"), help="folder to download and unpack into")
    p.add_argument("--url", help="download from this URL instead (a mirror)")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the server")
    _common(p, None)
    p = add("prepare", "build (and cache) the training rows of a data folder and summarise them", PREPARE_DOC,
            cmd_prepare, data_sub, "data prepare")
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    p.add_argument("--styles", nargs="+", help="styles (default: all)")
    p.add_argument("--gaits", nargs="+", help="gait codes (default: the locomotion gaits)")
    p.add_argument("--max-seconds", type=float, help="use only the first seconds of each clip")
    p.add_argument("--lpn", action="store_true", help="also build the 2022 LPN rows (local phases, style clips)")
    _common(p)

    p = add("train-base", "train the 2018 base PFNN with one CP adapter per style", TRAIN_DOC, cmd_train_base)
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    _common(p)
    _add_base_args(p, hidden=512, epochs=20, rank=30)

    p = add("sweep", "fine-tune new few-shot styles x dropout rates in one compiled sweep", SWEEP_DOC, cmd_sweep)
    p.add_argument("--sets", nargs="+", help="held-out styles of the data to learn (default: the styles the base "
                                             "was not trained on)")
    p.add_argument("--gaits", nargs="+", help="gaits of the few-shot clips (default: the base's)")
    p.add_argument("--clip", type=Path, nargs="+", help="your own BVH clips (the base's skeleton), one new style "
                                                        "per file named by its stem; replaces --sets")
    p.add_argument("--clip-range", type=float, nargs=2, metavar=("START", "END"), help="seconds of each --clip")
    p.add_argument("--asymmetric", action="store_true", help="do not mirror the --clip files")
    _common(p)
    _add_sweep_args(p, epochs=100)

    p = add("lpn", "train the 2022 LPN-FiLM network, test it, fine-tune it on new styles", LPN_DOC, cmd_lpn)
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
    p.add_argument("--rates", type=float, nargs="+", default=[0.1, 0.3, 0.5], help="fine-tuning dropout rates")
    _common(p)

    p = add("synthesize", "drive base and few-shot styles along paths: GIF, BVH, quality", SYNTH_DOC, cmd_synthesize)
    p.add_argument("--base-styles", nargs="+", help="base styles to show (default: the first)")
    p.add_argument("--sets", nargs="+", help="few-shot sets to show (default: the sweep's walking sets, up to 3)")
    p.add_argument("--blend", action="store_true", help="add a 50/50 blend of the first two few-shot sets")
    _common(p)
    _add_synth_args(p, paths=("circle", "zigzag"), seconds=8.0)

    p = add("render", "render BVH files side by side to a GIF (or MP4)", RENDER_DOC, cmd_render)
    p.add_argument("files", type=Path, nargs="+", help="BVH files")
    p.add_argument("--out", type=Path, default=Path("preview.gif"), help="output .gif or .mp4")
    p.add_argument("--start", type=float, default=0.0, help="first second to show")
    p.add_argument("--seconds", type=float, default=10.0, help="seconds to show")
    p.add_argument("--every", type=int, default=2, help="draw every n-th frame")
    _common(p, None)

    p = add("bench", "time the few-shot sweep against a loop of single runs, and the network", BENCH_DOC, cmd_bench)
    p.add_argument("--sets", type=int, default=4, help="few-shot sets (styles) in the sweep")
    p.add_argument("--rates", type=float, nargs="+", default=[0.3, 0.5, 0.7], help="dropout rates")
    p.add_argument("--frames", type=int, default=600, help="rows per set")
    p.add_argument("--sweep-epochs", type=int, default=5, help="epochs per pair")
    p.add_argument("--hidden", type=int, default=512, help="hidden units when the run has no base model")
    _common(p)
    return parser, subs


# --- helpers ------------------------------------------------------------------------------------

def _progress(args) -> bool:
    return not args.quiet


def _cpu_name() -> str:
    """The CPU's model name (Linux), else what :mod:`platform` knows."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.processor() or platform.machine()


def _machine() -> str:
    import jax

    return (f"{_cpu_name()}, {os.cpu_count()} cores, jax {jax.__version__} on "
            f"{jax.devices()[0].platform} x {jax.device_count()}")


def _elapsed(t0: float) -> str:
    s = time.perf_counter() - t0
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min"


def _check_positive(args, *names: str) -> None:
    for name in names:
        value = getattr(args, name, None)
        if value is not None and value <= 0:
            raise CLIError(f"--{name.replace('_', '-')} must be positive, got {value:g}")


def _base_settings(args, root: Path):
    from jaxstyle.mason2018 import pipeline

    base_styles, held_out = pipeline.split_styles(root, args.fewshot_styles, args.styles)
    gaits = tuple(args.gaits) if args.gaits else None
    settings = pipeline.BaseSettings(str(root), base_styles, gaits, hidden=args.hidden, rank=args.rank,
                                     epochs=args.base_epochs, max_seconds=args.max_seconds)
    return settings, held_out


def _sweep(run: Run, args, base, specs):
    from jaxstyle.mason2018 import pipeline

    t0 = time.perf_counter()
    result, paths, shots = pipeline.run_sweep(base, specs, run.dir / "sweep", rates=args.rates,
                                              epochs=args.sweep_epochs, adapter_dropout_only=args.adapter_dropout_only,
                                              cache=run.dir / "cache", progress=_progress(args))
    pairs = len(result.styles) * len(result.rates)
    run.say(f"sweep: {len(result.styles)} sets x {len(result.rates)} rates = {pairs} adapters, {args.sweep_epochs} "
            f"epochs each, in one compiled program: {result.seconds['sweep']:.1f} s; checks "
            f"{result.seconds['selection']:.1f} s; {_elapsed(t0)} in all")
    for line in pipeline.sweep_table(result):
        run.say(line)
    return result, paths, shots


def _default_sets(chosen: dict, limit: int = 3) -> list[str]:
    walks = [s for s in chosen if s.endswith("_FW")]
    return (walks or list(chosen))[:limit]


def _synthesize(run: Run, args, base, sweep_dir, shots, chosen, base_styles, sets, blend=False):
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.output import synthesis

    chars = pipeline.characters(base, sweep_dir, shots, chosen, base_styles=base_styles, fewshot_sets=sets,
                                blend=blend)
    t0 = time.perf_counter()
    result = synthesis.synthesize(base.params, base.normalisers, chars, base.skeleton, run.dir / "synthesis",
                                  path_names=args.paths, seconds=args.synth_seconds, speed=args.speed,
                                  foot_ik=args.foot_ik, mp4=args.mp4, every=args.every, contact_sheet=True,
                                  progress=_progress(args))
    run.say(f"synthesis: {len(chars)} characters x {len(args.paths)} paths, {result.frames:,} frames in one batched "
            f"rollout: {result.seconds:.2f} s ({result.frames / result.seconds:,.0f} frames/s); with GIF and BVH "
            f"writing {_elapsed(t0)}")
    for line in synthesis.quality_table(result.rows):
        run.say(line)
    return result


def _written(run: Run, title: str, files: Sequence[Path]) -> None:
    run.say(f"{title}:")
    for f in files:
        run.say(f"  {f}")


# --- commands -----------------------------------------------------------------------------------

DEMO_DOC = """\
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

GENERATE_DOC = """\
Write procedural stylised locomotion (jaxstyle.data.procedural) in the 100STYLE layout:
OUT/<Style>/<Style>_<GAIT>.bvh, Frame_Cuts.csv, Dataset_List.csv, and per clip its exact phase
(.phase), footsteps and contacts. Every jaxstyle command that takes --data reads it.
"""

FETCH_DOC = """\
Download a public dataset into --dest, resuming an interrupted download, verifying its MD5 and
unpacking it. 100style: the 100STYLE dataset (Mason, Starke, Komura 2022; CC BY 4.0), Zenodo
record 8127870. Offline, it fails at once and says how to place the files by hand.
"""

PREPARE_DOC = """\
Build the training rows of a style folder (PFNN features of Mason et al. 2018, and with
--lpn those of the 2022 paper), cache them in RUN/cache (later commands load them in well under a
second) and print per style its clips, rows, speed and step rate.
"""

TRAIN_DOC = """\
Train the base PFNN of Mason et al. 2018 (phase-functioned network with one CP residual adapter
per style, style-balanced half-mirrored batches, Adam 1e-4, dropout 0.3) on the base styles of
--data into RUN/base (checkpoints each epoch; re-running resumes; config, log.csv and the
normalisation statistics beside them). The styles left out are the later few-shot styles.
"""

SWEEP_DOC = """\
Learn new styles from a few seconds of motion (Mason et al. 2018 section 7): for every few-shot
set (one clip of --seconds per held-out style and gait, or your --clip files) and every dropout
rate, a fresh CP adapter is fine-tuned on the frozen base of RUN/base, all pairs in ONE jit(vmap)
program; each is validated on held-out frames and driven closed-loop, and a rate is chosen per
set. Writes RUN/sweep: results.csv, heatmap.png, chosen_rates.json, adapters/<set>/.
"""

LPN_DOC = """\
Mason, Starke & Komura 2022: train the local-phase network with FiLM layers driven by a style-clip
encoder on the training styles of --data (bone-length loss included), report test MSE and bone
length loss per style, then fine-tune only the FiLM generator on each new style at every dropout
rate in one compiled sweep and report the losses before and after. Writes RUN/lpn.
"""

SYNTH_DOC = """\
Drive characters in base styles and few-shot styles (the sweep's chosen adapters) along named
paths, all in one batched, jitted rollout; write RUN/synthesis/<path>.gif (styles side by side),
bvh/<style>_<path>.bvh and .npz, and quality.csv (foot skating, bone error, path error, beside
real clips of each style).
"""

RENDER_DOC = "Render BVH files (any skeleton, Y-up) side by side into an animated GIF, or MP4 with ffmpeg."

BENCH_DOC = """\
Measured side by side in one run: the few-shot sweep of --sets x rates pairs as ONE jit(vmap)
program against a Python loop of the same single runs, and the PFNN forward pass at batch 1 and
1024. Uses RUN/base when there is one, else a randomly initialised network of --hidden units.
The fuller benchmarks are the scripts in the repository's benchmarks/ folder.
"""


def demo_base_styles(base_styles: Sequence[str]) -> list[str]:
    """The demo's base styles on real data: all of them up to :data:`DEMO_MAX_BASE_STYLES`, else the
    paper's sweep base styles present (or the first ones), so the whole 100STYLE takes minutes."""
    if len(base_styles) <= DEMO_MAX_BASE_STYLES:
        return list(base_styles)
    paper = [s for s in PAPER_BASE_STYLES if s in base_styles]
    return (paper or list(base_styles))[:DEMO_MAX_BASE_STYLES]


def cmd_demo(args, run: Run) -> None:
    from jaxstyle.data import procedural
    from jaxstyle.mason2018 import pipeline

    t_all = time.perf_counter()
    _check_positive(args, "seconds", "synth_seconds", "data_seconds")
    run.say(f"jaxstyle demo on {_machine()}")
    if args.data is None:
        root = run.dir / "data"
        if not (root / "procedural.json").is_file():
            t0 = time.perf_counter()
            procedural.write_dataset(root, seconds=args.data_seconds, progress=_progress(args))
            run.say(f"data: procedural styles {', '.join(procedural.STYLES)} x gaits "
                    f"{', '.join(procedural.GAITS)}, {args.data_seconds:g} s each, written to {root} ({_elapsed(t0)})")
        else:
            run.say(f"data: procedural styles in {root} (written earlier)")
        if args.gaits is None:
            args.gaits = list(procedural.GAITS)
    else:
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
    run.save_settings(vars(args))  # with the defaults the data folder implied
    settings, held_out = _base_settings(args, root)
    t0 = time.perf_counter()
    base = pipeline.train_base(settings, run.dir / "base", cache=run.dir / "cache", progress=_progress(args),
                               log=run.say)
    run.say(f"base ready ({_elapsed(t0)})")
    specs = pipeline.fewshot_specs(root, held_out, args.seconds, settings.gaits)
    if not specs:
        raise CLIError(f"the few-shot styles {', '.join(held_out)} have no clip of the gaits "
                       f"{', '.join(settings.gaits or ['(all)'])} in {root}")
    result, report, shots = _sweep(run, args, base, specs)
    chosen = json.loads(report["chosen"].read_text())
    sets = _default_sets(chosen)
    base_styles = [s for s in ("Neutral", "Crouched") if s in base.dataset.styles] or list(base.dataset.styles[:1])
    synth = _synthesize(run, args, base, run.dir / "sweep", shots, chosen, base_styles, sets)
    run.say("")
    _written(run, "written", [run.dir / "base", report["csv"], report["heatmap"], report["chosen"]]
             + [f for f in synth.files if f.suffix in (".gif", ".mp4", ".csv", ".png")]
             + [run.dir / "synthesis" / "bvh" / f"({sum(f.suffix == '.bvh' for f in synth.files)} BVH files)"])
    run.say(f"config and log: {run.dir / 'config.json'}, {run.dir / 'log.txt'}")
    run.say(f"demo finished in {_elapsed(t_all)}")


def cmd_generate(args, run: None) -> None:
    from jaxstyle.data import procedural

    _check_positive(args, "seconds")
    t0 = time.perf_counter()
    root = procedural.write_dataset(args.out, styles=args.styles, gaits=tuple(args.gaits or procedural.GAITS),
                                    seconds=args.seconds, seed=args.seed, progress=_progress(args))
    styles = args.styles or list(procedural.STYLES)
    print(f"wrote {len(styles)} styles x {len(args.gaits or procedural.GAITS)} gaits of {args.seconds:g} s to {root} "
          f"({_elapsed(t0)}); use it with --data {root}")


def cmd_fetch(args, run: None) -> None:
    from jaxstyle.data import fetch

    folder = fetch.fetch(args.name, args.dest, url=args.url, timeout=args.timeout, progress=_progress(args))
    print(f"{args.name} is in {folder}; use it with --data {folder} (or set JAXSTYLE_MOCAP)")


def cmd_prepare(args, run: Run) -> None:
    import numpy as np

    from jaxstyle.data import datasets
    from jaxstyle.labels.contacts import estimate_units_per_meter
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.output import synthesis

    root = pipeline.style_root(args.data)
    styles = tuple(args.styles) if args.styles else pipeline.available_styles(root)
    specs = pipeline.clip_specs(root, styles, args.gaits, args.max_seconds)
    t0 = time.perf_counter()
    ds = pipeline.build(specs, run.dir / "cache", _progress(args))
    run.say(f"PFNN rows of {root}: {len(ds.inputs):,} rows x {ds.inputs.shape[1]} inputs -> {ds.outputs.shape[1]} "
            f"outputs from {len(ds.specs)} clips ({_elapsed(t0)}; cached in {run.dir / 'cache'})")
    upm = estimate_units_per_meter(datasets.load_clip(ds.specs[0]))
    run.say("| style | clips | rows train / val / test | speed m/s (median) | steps/s (median) |")
    run.say("|---|---|---|---|---|")
    for s in ds.styles:
        rows = ds.rows_of_style(s)
        clips = len(np.unique(ds.clip[rows]))
        split = [int((ds.split[rows] == k).sum()) for k in range(3)]
        speed = synthesis.own_speed(ds, rows, upm)
        dphase = np.mod(np.diff(ds.phases[rows, 0]), 1.0)
        steps = 2 * 60.0 * np.median(dphase[dphase < 0.5]) if (dphase < 0.5).any() else float("nan")
        run.say(f"| {s} | {clips} | {split[0]} / {split[1]} / {split[2]} | {speed:.2f} | {steps:.2f} |")
    if args.lpn:
        t0 = time.perf_counter()
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lpn = datasets.build_lpn_dataset(specs, cache_dir=run.dir / "cache", skip_short=True,
                                             progress=_progress(args))
        run.say(f"LPN rows: {len(lpn.inputs):,} rows x {lpn.inputs.shape[1]} inputs -> {lpn.outputs.shape[1]} "
                f"outputs, {len(lpn.clips):,} style clips ({_elapsed(t0)})")


def cmd_train_base(args, run: Run) -> None:
    from jaxstyle.mason2018 import pipeline

    root = pipeline.style_root(args.data)
    settings, held_out = _base_settings(args, root)
    run.say(f"train-base on {_machine()}; held out for few-shot: {', '.join(held_out)}")
    t0 = time.perf_counter()
    base = pipeline.train_base(settings, run.dir / "base", cache=run.dir / "cache", progress=_progress(args),
                               log=run.say)
    run.say(f"base ready in {_elapsed(t0)}: {run.dir / 'base'} (per-epoch validation losses in log.csv there, "
            f"{len(base.dataset.styles)} style adapters)")


def cmd_sweep(args, run: Run) -> None:
    from jaxstyle.mason2018 import pipeline

    _check_positive(args, "seconds", "sweep_epochs")
    base = pipeline.load_base(run.dir / "base", cache=run.dir / "cache", progress=_progress(args), log=lambda _: None)
    root = Path(base.settings.data)
    if args.clip:
        specs = pipeline.user_clip_specs(args.clip, not args.asymmetric,
                                         tuple(args.clip_range) if args.clip_range else None)
    else:
        sets = args.sets or [s for s in pipeline.available_styles(root) if s not in base.settings.styles]
        if not sets:
            raise CLIError(f"the base was trained on every style of {root}: name few-shot --sets or give --clip files")
        pipeline.split_styles(root, sets, base.settings.styles)  # checks the names
        specs = pipeline.fewshot_specs(root, sets, args.seconds, args.gaits or base.settings.gaits)
        if not specs:
            gaits = args.gaits or base.settings.gaits or ["(all)"]
            raise CLIError(f"no clip of {', '.join(sets)} with the gaits {', '.join(gaits)}")
    run.say(f"sweep on {_machine()}: base {run.dir / 'base'}")
    _, report, _ = _sweep(run, args, base, specs)
    _written(run, "written", list(report.values()))


def cmd_synthesize(args, run: Run) -> None:
    from jaxstyle.mason2018 import pipeline

    _check_positive(args, "synth_seconds", "every")
    base = pipeline.load_base(run.dir / "base", cache=run.dir / "cache", progress=_progress(args), log=lambda _: None)
    chosen, shots = pipeline.load_sweep(run.dir / "sweep", base, cache=run.dir / "cache")
    sets = args.sets if args.sets is not None else _default_sets(chosen)
    base_styles = args.base_styles or list(base.dataset.styles[:1])
    result = _synthesize(run, args, base, run.dir / "sweep", shots, chosen, base_styles, sets, blend=args.blend)
    _written(run, "written", [f for f in result.files if f.suffix != ".npz"])


def cmd_lpn(args, run: Run) -> None:
    import warnings

    import jax
    import numpy as np

    from jaxstyle.data import datasets
    from jaxstyle.mason2018 import pipeline
    from jaxstyle.mason2022 import train as train_lpn
    from jaxstyle.nn import film_generator as film
    from jaxstyle.nn.style_models import StyleModelConfig

    _check_positive(args, "epochs", "hidden", "generator_hidden", "filters")
    if args.finetune_steps < 0:
        raise CLIError(f"--finetune-steps must be >= 0, got {args.finetune_steps}")
    root = pipeline.style_root(args.data)
    styles, new_styles = pipeline.split_styles(root, args.new_styles, args.styles)
    cache = run.dir / "cache"
    run.say(f"lpn on {_machine()}: training styles {', '.join(styles)}; new styles {', '.join(new_styles)}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        base = datasets.build_lpn_dataset(pipeline.clip_specs(root, styles, args.gaits, args.max_seconds),
                                          cache_dir=cache, skip_short=True, progress=_progress(args))
        new = datasets.build_lpn_dataset(pipeline.clip_specs(root, new_styles, args.gaits, args.max_seconds),
                                         cache_dir=cache, skip_short=True, progress=_progress(args))
    skeleton = datasets.load_clip(base.specs[0])
    gen = film.FiLMConfig(clip_frames=base.clips.shape[1], clip_features=base.clips.shape[2], filters=args.filters,
                          hidden=args.generator_hidden, film_size=4 * args.hidden)
    mc = StyleModelConfig(num_styles=len(base.styles), hidden_size=args.hidden, input_size=base.inputs.shape[1],
                          output_size=base.outputs.shape[1], generator=gen)
    data = train_lpn.style_data(base, skeleton)
    t0 = time.perf_counter()
    state = train_lpn.train(data, train_lpn.LPNTrainConfig(model=mc, epochs=args.epochs), run.dir / "lpn",
                            progress=_progress(args))
    run.say(f"LPN-FiLM ({args.hidden} hidden, {args.epochs} epochs, {int((base.split == 0).sum()):,} training rows) "
            f"ready in {_elapsed(t0)}: {run.dir / 'lpn'}")
    params = state["params"]
    test = train_lpn.evaluate(params, mc, data, "test")
    run.say("| style | test MSE (normalised) | test bone-length loss (cm) |\n|---|---|---|")
    for s, style in enumerate(base.styles):
        run.say(f"| {style} | {test['mse'][s]:.4f} | {100 * test['bll'][s]:.2f} |")
    lines = []
    if args.finetune_steps > 0:
        new_data = train_lpn.style_data(new, skeleton, base=base)
        ft = train_lpn.FiLMFinetuneConfig(rates=tuple(args.rates), max_steps=args.finetune_steps, epochs=100)
        t0 = time.perf_counter()
        gens, _ = train_lpn.finetune_film_sweep(params, mc, new_data, ft, chunk_steps=10, progress=_progress(args))
        run.say(f"\nfine-tuned the FiLM generator alone: {len(new.styles)} new styles x {len(ft.rates)} rates, "
                f"{args.finetune_steps} steps each, one compiled sweep ({_elapsed(t0)})")
        before = train_lpn.evaluate(params, mc, new_data, "test")
        lines = ["| new style | test MSE before | " + " | ".join(f"after @ {r:g}" for r in ft.rates) + " |",
                 "|---|---|" + "---|" * len(ft.rates)]
        for s, style in enumerate(new.styles):
            after = [train_lpn.evaluate(train_lpn.with_generator(params, gens, s, r), mc, new_data, "test",
                                        styles=[s])["mse"][0] for r in range(len(ft.rates))]
            lines.append(f"| {style} | {before['mse'][s]:.4f} | " + " | ".join(f"{a:.4f}" for a in after) + " |")
        for line in lines:
            run.say(line)
        leaves = jax.tree_util.tree_leaves_with_path(gens)
        np.savez(run.dir / "lpn" / "finetuned_generators.npz",  # leading axes (new style, rate)
                 **{jax.tree_util.keystr(path): np.asarray(v) for path, v in leaves})
    (run.dir / "lpn" / "results.md").write_text("\n".join(lines) + "\n")
    _written(run, "written", [run.dir / "lpn", run.dir / "lpn" / "results.md"])


def cmd_render(args, run: None) -> None:
    from jaxstyle.labels.contacts import estimate_units_per_meter
    from jaxstyle.motion.bvh import read_bvh
    from jaxstyle.motion.kinematics import global_positions
    from jaxstyle.output import preview

    _check_positive(args, "seconds", "every")
    if args.start < 0:
        raise CLIError(f"--start must be >= 0, got {args.start:g}")
    if args.out.suffix.lower() not in (".gif", ".mp4"):
        raise CLIError(f"--out {args.out}: the name must end in .gif or .mp4")
    chars, parents, fps, upm = [], None, None, None
    for f in args.files:
        if not f.is_file():
            raise CLIError(f"{f}: no such file")
        m = read_bvh(f)
        a = int(round(args.start * m.fps))
        if a >= m.num_frames:
            raise CLIError(f"{f}: --start {args.start:g} s is past its end ({m.duration:.1f} s)")
        m = m.frames(a, a + int(round(args.seconds * m.fps)))
        if parents is None:
            parents, fps, upm = m.parents, m.fps, estimate_units_per_meter(m)
        elif len(m.parents) != len(parents) or m.fps != fps:
            raise CLIError(f"{f}: a different skeleton or frame rate from {args.files[0]}; render them separately")
        chars.append(global_positions(m))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    titles = [f.stem for f in args.files]
    if args.out.suffix.lower() == ".gif":
        out = preview.render_gif(args.out, chars, parents, fps, titles=titles, units_per_meter=upm, every=args.every,
                                 progress=_progress(args))
    else:
        out = preview.render_mp4(args.out, chars, parents, fps, titles=titles, units_per_meter=upm, every=args.every,
                                 progress=_progress(args))
    print(f"wrote {out}")


def cmd_bench(args, run: Run) -> None:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxstyle.mason2018 import fewshot
    from jaxstyle.nn import pfnn
    from jaxstyle.timing import time_call
    from jaxstyle.train import scan

    _check_positive(args, "sets", "frames", "sweep_epochs", "hidden")
    if (run.dir / "base" / "base.json").is_file():
        from jaxstyle.mason2018 import pipeline

        base = pipeline.load_base(run.dir / "base", cache=run.dir / "cache", progress=False, log=lambda _: None)
        model, params, what = base.model, base.params, f"the base of {run.dir / 'base'}"
    else:
        model = pfnn.PFNNConfig(hidden_size=args.hidden)
        params, what = pfnn.init_pfnn(jax.random.PRNGKey(0), model), "a random network"
    run.say(f"bench on {_machine()}: {what}, {model.input_size} -> {model.hidden_size} -> {model.output_size}, "
            f"CP rank {model.rank}")
    rng = np.random.default_rng(0)
    n = args.sets * args.frames
    x = jnp.asarray(rng.standard_normal((n, model.input_size)), jnp.float32)
    y = jnp.asarray(rng.standard_normal((n, model.output_size)), jnp.float32)
    phase = jnp.asarray(rng.random(n), jnp.float32)
    rows = [np.arange(s * args.frames, (s + 1) * args.frames) for s in range(args.sets)]
    config = fewshot.SweepConfig(model=model, epochs=args.sweep_epochs, rates=tuple(args.rates))
    batches, mask = scan.sweep_batches(rows, config.epochs, config.batch_size)

    def sweep():
        return fewshot.finetune_sweep(params, x, y, phase, batches, mask, config)

    def loop():
        return [fewshot.finetune_one(params, x, y, phase, batches[s], mask[s], rate,
                                     scan.pair_key(config.seed, s, r), config)[0]
                for s in range(args.sets) for r, rate in enumerate(config.rates)]

    timings = {}
    for name, fn in (("sweep", sweep), ("loop", loop)):
        jax.block_until_ready(fn())  # compile
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        timings[name] = time.perf_counter() - t0
    pairs = args.sets * len(config.rates)
    run.say(f"few-shot fine-tuning, {pairs} pairs x {batches.shape[1]} steps of batch {config.batch_size}: "
            f"one jit(vmap) sweep {timings['sweep']:.2f} s, loop of single runs {timings['loop']:.2f} s, "
            f"ratio {timings['loop'] / timings['sweep']:.2f}x ({timings['sweep'] / pairs:.3f} s per pair)")
    forward = jax.jit(lambda xb, pb: pfnn.pfnn_apply(params, xb, pb))
    for b in (1, 1024):
        xb, pb = x[:b] if b <= n else jnp.tile(x, (b // n + 1, 1))[:b], jnp.resize(phase, (b,))
        mean, std = time_call(lambda xb=xb, pb=pb: forward(xb, pb), calls=50 if b == 1 else 10, runs=3)
        run.say(f"PFNN forward, batch {b}: {1e3 * mean:.3f} +- {1e3 * std:.3f} ms ({b / mean:,.0f} frames/s)")
        timings[f"forward_batch_{b}_ms"] = 1e3 * mean
    (run.dir / "bench.json").write_text(json.dumps({"machine": _machine(), **timings}, indent=2))
    run.say(f"written: {run.dir / 'bench.json'}")


# --- entry point --------------------------------------------------------------------------------

def _command_name(args) -> str:
    return args.command if args.command != "data" else f"data {args.data_command}"


def _apply_config(parser, subs, args, argv):
    """Re-parse with the TOML file's settings as defaults (explicit flags still win)."""
    name = _command_name(args)
    try:
        settings = tomllib.loads(Path(args.config).read_text())
    except FileNotFoundError:
        raise CLIError(f"--config {args.config}: no such file") from None
    except tomllib.TOMLDecodeError as e:
        raise CLIError(f"--config {args.config}: not valid TOML ({e})") from None
    table = settings.get(name, settings.get(name.replace(" ", "-"), {}))
    flat = {k: v for k, v in settings.items() if not isinstance(v, dict)}
    flat.update(table if isinstance(table, dict) else {})
    sub = subs[name]
    dests = {a.dest: a for a in sub._actions}
    values = {}
    for key, value in flat.items():
        dest = key.replace("-", "_")
        if dest not in dests or dest in ("help", "config"):
            known = sorted(d.replace("_", "-") for d in dests if d not in ("help", "config", "handler"))
            raise CLIError(f"--config {args.config}: unknown setting {key!r} for `jaxstyle {name}`; known: "
                           f"{', '.join(known)}")
        action = dests[dest]
        values[dest] = action.type(value) if action.type is not None and isinstance(value, str) else value
    sub.set_defaults(**values)
    return parser.parse_args(argv)


KNOWN_ERRORS: tuple[type[BaseException], ...] = (CLIError, FileNotFoundError, NotADirectoryError, PermissionError,
                                                 ValueError, KeyError)


NEEDS_BASE = ("sweep", "synthesize")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status (0 done, 1 failed, 2 bad arguments)."""
    from jaxstyle.errors import JaxstyleError

    argv = list(sys.argv[1:] if argv is None else argv)
    parser, subs = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    if args.command == "data" and args.data_command is None:
        subs["data"].print_help()
        return 2
    name = _command_name(args)
    handler: Callable = args.handler
    errors = KNOWN_ERRORS + (JaxstyleError,)
    with contextlib.suppress(ImportError):
        from jaxstyle.data.fetch import FetchError

        errors += (FetchError,)
    run = None
    try:
        if args.config is not None:
            args = _apply_config(parser, subs, args, argv)
        settings = vars(args)
        if name in NEEDS_BASE and not (Path(args.run) / "base" / "base.json").is_file():
            raise CLIError(f"no base model in {Path(args.run) / 'base'}: train one first with "
                           "`jaxstyle train-base --data PATH --run RUN` (or run `jaxstyle demo`)")
        if "run" in vars(args):
            run = Run(args.run, name, settings, argv)
        handler(args, run)
    except errors as e:
        if args.debug:
            raise
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"jaxstyle {name}: error: {message}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"jaxstyle {name}: interrupted (re-run the same command to resume)", file=sys.stderr)
        return 130
    finally:
        if run is not None:
            run.close()
    return 0


def entry_point() -> None:
    """The console script."""
    sys.exit(main())
