"""Summarise every BVH file under a motion capture folder: size, rate, skeleton, speed, facing.

    python experiments/inspect_mocap.py [--root ../shared/mocap] [--fps 60]

Reads each clip, resamples it to ``--fps``, converts it to metres (the skeleton is scaled to
``--height`` metres tall), and prints one markdown row per clip: frames, duration, joints,
skeleton height in file units, mean ground speed, and how well the facing direction follows the
direction of travel (+1 forwards, -1 backwards, ~0 sideways or idle).
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

import jaxstyle as js


@dataclasses.dataclass(frozen=True)
class Config:
    root: Path
    fps: float = 60.0
    height: float = 1.75  # metres; the papers' data is scaled to a human height


def summarise(path: Path, cfg: Config) -> str:
    motion = js.read_bvh(path)
    units_height = js.skeleton_height(motion)
    clip = js.scale(js.resample(motion, cfg.fps), cfg.height / units_height)
    traj = js.root_trajectory(clip)
    if clip.num_frames > 2:
        vel = np.gradient(traj, axis=0) * clip.fps
        speed = np.linalg.norm(vel, axis=1)
        facing = js.facing_directions(clip, smooth_sigma=10)
        along = float((facing * vel).sum() / max(speed.sum(), 1e-9))
        mean_speed = float(speed.mean())
    else:
        along, mean_speed = float("nan"), 0.0
    return (f"| {path.relative_to(cfg.root).as_posix()} | {motion.num_frames} | {motion.fps:g} | "
            f"{clip.duration:.1f} | {motion.num_joints} | {units_height:.2f} | {mean_speed:.2f} | {along:+.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--root", type=Path, default=js.default_mocap_dir())
    parser.add_argument("--fps", type=float, default=60.0)
    args = parser.parse_args()
    cfg = Config(root=args.root, fps=args.fps)
    files = sorted(cfg.root.rglob("*.bvh"))
    if not files:
        raise SystemExit(f"no .bvh files under {cfg.root} (set --root or {js.data.locate.ENV_VAR})")
    print("| file | frames | fps | seconds | joints | height (file units) | speed (m/s) | facing . travel |")
    print("|---|---|---|---|---|---|---|---|")
    for path in files:
        print(summarise(path, cfg))


if __name__ == "__main__":
    main()
