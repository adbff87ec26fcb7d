"""Plot source functions, fitted local phases and foot contacts of a clip (2022 paper, Figure 4).

    python experiments/plot_local_phases.py 100style/Angry/Angry_FW.bvh --start 1200 --seconds 4
    python experiments/plot_local_phases.py my_clip.bvh --foot-source auto --out runs/figures/my_clip.png

The clip is a path, absolute or relative to the motion capture folder ($JAXSTYLE_MOCAP).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jaxstyle as js
from jaxstyle.labels.local_phase import LocalPhaseConfig, local_phases
from jaxstyle.output.viz import plot_local_phases


@dataclasses.dataclass(frozen=True)
class Config:
    clip: str = "100style/Angry/Angry_FW.bvh"
    start: int = 1200
    seconds: float = 4.0
    foot_source: str = "contact"
    out: Path | None = None


def run(config: Config) -> Path:
    path = Path(config.clip)
    if not path.is_file():
        path = js.mocap_dir() / config.clip
    motion = js.read_bvh(path)
    result = local_phases(motion, LocalPhaseConfig(foot_source=config.foot_source))
    stop = min(motion.num_frames, config.start + int(round(config.seconds * motion.fps)))
    fig = plot_local_phases(result, config.start, stop, title=f"{path.stem}: local phases",
                            marker=(config.start + stop) // 2)
    out = config.out or Path("runs/figures") / f"{path.stem}_local_phases.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, facecolor=fig.get_facecolor())
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clip", nargs="?", default=Config.clip)
    parser.add_argument("--start", type=int, default=Config.start, help="first frame")
    parser.add_argument("--seconds", type=float, default=Config.seconds, help="length shown")
    parser.add_argument("--foot-source", default=Config.foot_source, choices=["contact", "free", "auto"])
    parser.add_argument("--out", type=Path, default=None,
                        help="PNG path (default runs/figures/<clip>_local_phases.png)")
    args = parser.parse_args()
    out = run(Config(args.clip, args.start, args.seconds, args.foot_source, args.out))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
