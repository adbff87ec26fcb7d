"""BVH reading and forward kinematics speed, side by side with np.loadtxt of the same motion block.

    python benchmarks/bvh_io.py [--file 100style/Angry/Angry_FW.bvh] [--repeats 15]

Prints the median of ``--repeats`` timings after one warm-up (which pays pandas' import); reading
and np.loadtxt are timed alternately in the same loop.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import numpy as np

import jaxstyle as js


def _median_seconds(*fns, repeats: int) -> list[float]:
    """Median wall time of each function, measured alternately so machine drift hits all alike."""
    for fn in fns:
        fn()  # warm-up (imports, caches)
    times = [[] for _ in fns]
    for _ in range(repeats):
        for fn, ts in zip(fns, times, strict=True):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
    return [statistics.median(ts) for ts in times]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--file", default="100style/Angry/Angry_FW.bvh", help="path relative to the mocap folder")
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    path = js.mocap_dir() / args.file

    motion = js.read_bvh(path)
    lines = path.read_text().split("\n")
    header_lines = lines.index("MOTION") + 3  # MOTION, Frames:, Frame Time:

    read_s, loadtxt_s = _median_seconds(lambda: js.read_bvh(path), lambda: np.loadtxt(path, skiprows=header_lines),
                                        repeats=args.repeats)
    (fk_s,) = _median_seconds(lambda: js.global_transforms(motion), repeats=args.repeats)

    joint_frames = motion.num_frames * motion.num_joints
    print(f"file: {path.name}  ({motion.num_frames} frames x {motion.num_joints} joints, "
          f"{sum(len(c) for c in motion.channels)} channels, {path.stat().st_size / 1e6:.1f} MB)")
    print(f"machine: {platform.machine()}, {platform.processor() or 'cpu'}, "
          f"{__import__('os').cpu_count()} cores, numpy {np.__version__}")
    for label, seconds in (("read_bvh (parse + Euler->quaternion):", read_s),
                           ("np.loadtxt of the same motion block: ", loadtxt_s)):
        print(f"{label} {seconds * 1e3:8.2f} ms   {motion.num_frames / seconds:12,.0f} frames/s")
    print(f"  ratio read_bvh / loadtxt: {read_s / loadtxt_s:.2f}  (target <= 1.00)")
    print(f"forward kinematics (rotations + positions): {fk_s * 1e3:8.2f} ms   "
          f"{joint_frames / fk_s / 1e6:8.2f} M joint-frames/s  (target > 1)")


if __name__ == "__main__":
    main()
