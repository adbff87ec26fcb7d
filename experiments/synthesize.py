"""Drive characters along user paths in a base style and two few-shot styles, then write a GIF
per path, a BVH (and .npz) per style and path, a contact sheet, and quality figures beside those
of real motion of each style (Mason et al. 2018 section 7.1's runtime; the 2022 paper's section
4.4 foot-contact IK: feet locked while planted, off with ``--no-foot-lock``).

    python experiments/synthesize.py [--styles Elated_FW,Rushed_FW] [--base-style Neutral]
        [--paths straight,circle,zigzag,stop_and_go,speed_ramp] [--seconds 8] [--speed M_PER_S]
        [--no-foot-lock] [--mp4] [--out runs/synthesis]

It builds on ``experiments/fewshot_sweep.py`` (run it first): its base PFNN (``runs/fewshot/base``)
and the few-shot adapters it chose (``runs/fewshot/sweep``). Every (style, path) character is
generated in ONE batched, jitted rollout (:func:`jaxstyle.output.synthesis.synthesize`), each from
a real pose of its own style; a fourth character walks an exact 50/50 blend of the two few-shot
styles' CP adapters. Written to ``--out``: ``<path>.gif``, ``bvh/<style>_<path>.bvh`` and ``.npz``,
``contact_sheet.png``, ``quality.csv`` and ``results.md``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from jaxstyle.control import paths
from jaxstyle.data import folders
from jaxstyle.mason2018 import base_model, pipeline
from jaxstyle.output import synthesis


def names(text: str) -> list[str]:
    return [s.strip() for s in text.split(",") if s.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--styles", type=names, default="Elated_FW,Rushed_FW", help="few-shot sets of the sweep")
    parser.add_argument("--base-style", default="Neutral", help="a base training style (its adapter)")
    parser.add_argument("--paths", type=names, default="straight,circle,zigzag,stop_and_go,speed_ramp",
                        help=f"any of {', '.join(paths.PATHS)}")
    parser.add_argument("--seconds", type=float, default=8.0)
    parser.add_argument("--speed", type=float, help="walking speed, m/s (default: each style's own median speed)")
    parser.add_argument("--no-foot-lock", dest="foot_lock", action="store_false",
                        help="write the network's feet as they are (locked while planted by default)")
    parser.add_argument("--mp4", action="store_true", help="also write MP4s (needs ffmpeg)")
    parser.add_argument("--base", type=Path, default=Path("runs/fewshot/base"))
    parser.add_argument("--sweep", type=Path, default=Path("runs/fewshot/sweep"))
    parser.add_argument("--out", type=Path, default=Path("runs/synthesis"))
    parser.add_argument("--cache", type=Path, default=Path("runs/cache"))
    a = parser.parse_args()
    unknown = [p for p in a.paths if p not in paths.PATHS]
    if unknown:
        parser.error(f"unknown paths {unknown}; known: {', '.join(paths.PATHS)}")
    try:
        base = base_model.load_base(a.base, cache=a.cache)
        chosen, shots = pipeline.load_sweep(a.sweep, base, cache=a.cache)
        chars = pipeline.characters(base, a.sweep, shots, chosen, base_styles=[a.base_style], fewshot_sets=a.styles,
                                    blend=len(a.styles) >= 2)
        result = synthesis.synthesize(base.character_model(), chars, base.skeleton, a.out, synthesis.SynthesisOptions(
            path_names=tuple(a.paths), seconds=a.seconds, speed=a.speed, foot_lock=a.foot_lock, mp4=a.mp4,
            contact_sheet=True, progress=True))
    except folders.PipelineError as e:
        parser.error(f"{e} (run python experiments/fewshot_sweep.py first)")
    print("speeds (m/s): " + ", ".join(f"{n} {v:.2f}" for n, v in result.speeds.items()))
    print(f"\n{result.summary(len(chars), len(a.paths))}")
    lines = synthesis.quality_table(result.rows)
    (a.out / "results.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"\nwritten to {a.out}: {len(result.files) + 1} files, e.g. " + ", ".join(map(str, result.files[:4])))


if __name__ == "__main__":
    main()
