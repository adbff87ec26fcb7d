"""``jaxstyle data generate|fetch|prepare``: make, download or inspect motion data."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

from jaxstyle.cli.args import add_common, add_joint_map_arg, check_positive, finite, joint_map
from jaxstyle.cli.common import DATA_HELP, Run, elapsed, ensure_folder, progress

NAME = "data"
HELP = "make, download or inspect motion data"
DOC = "Make, download or inspect motion data."

GENERATE_HELP = "write procedural stylised locomotion in the 100STYLE layout"
GENERATE_DOC = """\
Write procedural stylised locomotion (jaxstyle.data.procedural) in the 100STYLE layout:
OUT/<Style>/<Style>_<GAIT>.bvh, Frame_Cuts.csv, Dataset_List.csv, and per clip its exact phase
(.phase), footsteps and contacts. Every jaxstyle command that takes --data reads it.
"""

FETCH_HELP = "download a public dataset (resumable, checksummed) and unpack it"
FETCH_DOC = """\
Download a public dataset into --dest, resuming an interrupted download, verifying its MD5 and
unpacking it. 100style: the 100STYLE dataset (Mason, Starke, Komura 2022; CC BY 4.0), Zenodo
record 8127870. Offline, it fails at once and says how to place the files by hand.
"""

PREPARE_HELP = "build (and cache) the training rows of a data folder and summarise them"
PREPARE_DOC = """\
Build the training rows of a style folder (PFNN features of Mason et al. 2018, and with
--lpn those of the 2022 paper), cache them in RUN/cache (later commands load them in well under a
second) and print per style its clips, rows, speed and step rate.
"""


def add_generate_arguments(p) -> None:
    p.add_argument("--out", type=Path, default=Path("data/procedural"), help="folder to write")
    p.add_argument("--styles", nargs="+", help="styles (default: all)")
    p.add_argument("--gaits", nargs="+", help="gaits (default: FW FR)")
    p.add_argument("--seconds", type=finite, default=24.0, help="seconds per clip")
    p.add_argument("--seed", type=int, default=0)
    add_common(p, None)


def add_fetch_arguments(p) -> None:
    p.add_argument("name", help="dataset name, e.g. 100style")
    p.add_argument("--dest", type=Path, default=Path("data"), help="folder to download and unpack into")
    p.add_argument("--url", help="download from this URL instead (a mirror)")
    p.add_argument("--timeout", type=finite, default=10.0, help="seconds to wait for the server")
    add_common(p, None)


def add_prepare_arguments(p) -> None:
    p.add_argument("--data", type=Path, required=True, help=DATA_HELP)
    p.add_argument("--styles", nargs="+", help="styles (default: all)")
    p.add_argument("--gaits", nargs="+", help="gait codes (default: the locomotion gaits)")
    p.add_argument("--max-seconds", type=finite, help="use only the first seconds of each clip")
    p.add_argument("--lpn", action="store_true", help="also build the 2022 LPN rows (local phases, style clips)")
    add_joint_map_arg(p)
    add_common(p)


def generate(args, run: None) -> None:
    from jaxstyle.data import procedural

    check_positive(args, "seconds")
    ensure_folder(args.out, "--out")
    t0 = time.perf_counter()
    root = procedural.write_dataset(args.out, styles=args.styles, gaits=tuple(args.gaits or procedural.GAITS),
                                    seconds=args.seconds, seed=args.seed, progress=progress(args))
    styles = args.styles or list(procedural.STYLES)
    print(f"wrote {len(styles)} styles x {len(args.gaits or procedural.GAITS)} gaits of {args.seconds:g} s to {root} "
          f"({elapsed(t0)}); use it with --data {root}")


def fetch(args, run: None) -> None:
    from jaxstyle.data import fetch

    folder = fetch.fetch(args.name, args.dest, url=args.url, timeout=args.timeout, progress=progress(args))
    print(f"{args.name} is in {folder}; use it with --data {folder} (or set JAXSTYLE_MOCAP)")


def prepare(args, run: Run) -> None:
    from jaxstyle.data import datasets, folders
    from jaxstyle.mason2018 import base_model, pipeline

    root = folders.style_root(args.data)
    styles = tuple(args.styles) if args.styles else folders.available_styles(root)
    specs = folders.clip_specs(root, styles, args.gaits, args.max_seconds, joint_map(args))
    t0 = time.perf_counter()
    ds = base_model.build(specs, run.dir / "cache", progress(args))
    run.say(f"PFNN rows of {root}: {len(ds.inputs):,} rows x {ds.inputs.shape[1]} inputs -> {ds.outputs.shape[1]} "
            f"outputs from {len(ds.specs)} clips ({elapsed(t0)}; cached in {run.dir / 'cache'})")
    for line in pipeline.style_table(ds):
        run.say(line)
    if args.lpn:
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            lpn = datasets.build_lpn_dataset(specs, cache_dir=run.dir / "cache", skip_short=True,
                                             progress=progress(args))
        run.say(f"LPN rows: {len(lpn.inputs):,} rows x {lpn.inputs.shape[1]} inputs -> {lpn.outputs.shape[1]} "
                f"outputs, {len(lpn.clips):,} style clips ({elapsed(t0)})")


# (sub-command, help, description, add_arguments, handler)
ACTIONS = (("generate", GENERATE_HELP, GENERATE_DOC, add_generate_arguments, generate),
           ("fetch", FETCH_HELP, FETCH_DOC, add_fetch_arguments, fetch),
           ("prepare", PREPARE_HELP, PREPARE_DOC, add_prepare_arguments, prepare))
