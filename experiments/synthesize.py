"""Drive characters along user paths in a base style and two few-shot styles, then write a GIF
per path, a BVH (and .npz) per style and path, a contact sheet, and quality figures beside those
of real motion of each style (Mason et al. 2018 section 7.1's runtime; the 2022 paper's section
4.4 foot-contact IK with ``--foot-ik``).

    python experiments/synthesize.py [--styles Elated_FW,Rushed_FW] [--base-style Neutral]
        [--paths straight,circle,zigzag,stop_and_go,speed_ramp] [--seconds 8] [--speed M_PER_S]
        [--foot-ik] [--mp4] [--out runs/synthesis]

It builds on ``experiments/fewshot_sweep.py``: the base PFNN (trained into ``runs/fewshot/base``
if it is not there yet, about 6 min on 2 CPU cores) and the few-shot adapters it chose
(``runs/fewshot/sweep/adapters/<set>``; run that script first). Every (style, path) character is
generated in ONE batched, jitted ``lax.scan`` (``jaxstyle.control.controller.rollout_batch``); each
starts from a real pose of its own style chosen to match the requested speed. The base style is
the base network with that training style's adapter; a fourth character walks a 50/50 blend of
the two few-shot styles (``jaxstyle.nn.pfnn.blend_adapters``, exact for CP adapters).

Written to ``--out``: ``<path>.gif`` (styles side by side), ``bvh/<style>_<path>.bvh`` and
``.npz``, ``contact_sheet.png`` (the first path), ``quality.csv`` and ``results.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

import jaxstyle as js
from jaxstyle.control import paths
from jaxstyle.data import datasets
from jaxstyle.mason2018 import pipeline
from jaxstyle.output import synthesis

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fewshot_sweep  # noqa: E402  (the base model and few-shot sets of the sweep experiment)


@dataclasses.dataclass(frozen=True)
class Config:
    styles: tuple[str, ...] = ("Elated_FW", "Rushed_FW")
    base_style: str = "Neutral"
    paths: tuple[str, ...] = ("straight", "circle", "zigzag", "stop_and_go", "speed_ramp")
    seconds: float = 8.0
    speed: float | None = None  # None: each style walks at its own median speed
    foot_ik: bool = False
    mp4: bool = False
    base: Path = Path("runs/fewshot/base")
    sweep: Path = Path("runs/fewshot/sweep")
    out: Path = Path("runs/synthesis")


def parse_args() -> Config:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    d = Config()
    parser.add_argument("--styles", default=",".join(d.styles), help="few-shot sets (adapters of the sweep)")
    parser.add_argument("--base-style", default=d.base_style, help="a base training style (its adapter)")
    parser.add_argument("--paths", default=",".join(d.paths), help=f"any of {', '.join(paths.PATHS)}")
    parser.add_argument("--seconds", type=float, default=d.seconds)
    parser.add_argument("--speed", type=float, default=d.speed,
                        help="walking speed of the paths, m/s (default: each style's own median speed)")
    parser.add_argument("--foot-ik", action="store_true", help="pin the feet in contact in the BVH files")
    parser.add_argument("--mp4", action="store_true", help="also write MP4s (needs ffmpeg)")
    parser.add_argument("--base", type=Path, default=d.base)
    parser.add_argument("--sweep", type=Path, default=d.sweep)
    parser.add_argument("--out", type=Path, default=d.out)
    a = parser.parse_args()
    config = Config(tuple(s.strip() for s in a.styles.split(",") if s.strip()), a.base_style,
                    tuple(p.strip() for p in a.paths.split(",") if p.strip()), a.seconds, a.speed, a.foot_ik, a.mp4,
                    a.base, a.sweep, a.out)
    unknown = [p for p in config.paths if p not in paths.PATHS]
    if unknown:
        parser.error(f"unknown paths {unknown}; known: {', '.join(paths.PATHS)}")
    if config.base_style not in fewshot_sweep.BASE_STYLES:
        parser.error(f"--base-style must be a base training style: {', '.join(fewshot_sweep.BASE_STYLES)}")
    missing = [s for s in config.styles if not (config.sweep / "adapters" / s).is_dir()]
    if missing:
        parser.error(f"no few-shot adapter for {missing} in {config.sweep / 'adapters'}; "
                     "run python experiments/fewshot_sweep.py first")
    return config


def main() -> None:
    config = parse_args()
    mocap = js.mocap_dir()
    fs_config = fewshot_sweep.Config(base=config.base)
    base = fewshot_sweep.base_model(mocap, fs_config)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        shots = datasets.build_pfnn_dataset(fewshot_sweep.fewshot_specs(mocap / "100style", fs_config.seconds),
                                            cache_dir=fs_config.cache)
    chosen = json.loads((config.sweep / "chosen_rates.json").read_text())

    # one character per style (its adapter, and the rows its start pose and own speed come from),
    # and an exact blend of the first two few-shot adapters (style interpolation)
    chars = pipeline.characters(base, config.sweep, shots, chosen, base_styles=[config.base_style],
                                fewshot_sets=config.styles, blend=len(config.styles) >= 2)
    result = synthesis.synthesize(base.params, base.normalisers, chars, base.skeleton, config.out,
                                  path_names=config.paths, seconds=config.seconds, speed=config.speed,
                                  foot_ik=config.foot_ik, mp4=config.mp4, every=2, contact_sheet=True,
                                  progress=True)
    print("speeds (m/s): " + ", ".join(f"{n} {v:.2f}" for n, v in result.speeds.items()))
    print(f"\n{len(chars) * len(config.paths)} characters x {result.frames // (len(chars) * len(config.paths))} "
          f"frames in one batched rollout: {result.seconds:.2f} s ({result.frames / result.seconds:,.0f} frames/s)")
    lines = synthesis.quality_table(result.rows)
    (config.out / "results.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"\nwritten to {config.out}: {len(result.files) + 1} files, e.g. "
          + ", ".join(str(w) for w in result.files[:4]))


if __name__ == "__main__":
    main()
