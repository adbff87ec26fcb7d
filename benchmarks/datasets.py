"""Building every dataset of the shared sample: cold (empty cache) and warm (from the cache).

    python benchmarks/datasets.py [--cache DIR]

Builds, side by side in one run: the 2022 LPN dataset of all 100STYLE clips (cut by
Frame_Cuts.csv, symmetric styles mirrored) and the 2018 PFNN dataset of the Xia clips (mirrored)
plus the labelled PFNN captures, at 60 fps. Cold runs in a fresh cache folder; warm repeats the
same calls, which only hash the inputs and load the cached arrays.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
import warnings
from pathlib import Path

import jaxstyle as js
from jaxstyle.data import clips, datasets


def build_all(mocap: Path, cache: Path) -> tuple[datasets.Dataset, datasets.Dataset]:
    lpn = datasets.build_lpn_dataset(clips.specs_100style(mocap / "100style"), cache_dir=cache)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the clips too short for the trajectory window are skipped
        specs = clips.specs_xia(mocap / "xia") + clips.specs_pfnn(mocap / "pfnn_excerpt")
        pfnn = datasets.build_pfnn_dataset(specs, cache_dir=cache, skip_short=True)
    return lpn, pfnn


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cache", type=Path, default=None, help="cache folder (default: a fresh temporary one)")
    args = parser.parse_args()
    mocap = js.mocap_dir()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.cache or Path(tmp)
        t0 = time.perf_counter()
        lpn, pfnn = build_all(mocap, cache)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        build_all(mocap, cache)
        warm = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in cache.glob("*.npz")) / 2**20
    print(f"LPN : {len(lpn.specs)} clips, {len(lpn.styles)} styles, inputs {lpn.inputs.shape}, "
          f"outputs {lpn.outputs.shape}, style clips {lpn.clips.shape}")
    print(f"PFNN: {len(pfnn.specs)} clips, {len(pfnn.styles)} styles, inputs {pfnn.inputs.shape}, "
          f"outputs {pfnn.outputs.shape}")
    print(f"cold build {cold:.1f} s (target < 60 s), from cache {warm:.2f} s (target < 2 s), cache {size:.0f} MiB")


if __name__ == "__main__":
    main()
