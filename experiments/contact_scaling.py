"""Foot contacts of the shared skeletons under both contact rules, and their invariance.

    python experiments/contact_scaling.py [--mocap DIR]

Prints, per shared set (100STYLE, the 30 fps 100STYLE-skeleton run, Xia and the PFNN excerpt, the
last two on Holden's CMU skeleton), the fraction of frames with each foot in contact under the
paper's rule (``paper2022``: 0.01 m, 0.15 m/s, metres guessed from the skeleton's height) and the
default ``scaled`` rule (the same thresholds for a body of the skeleton's leg length, speeds over
2/60 s); then, for a few clips, how many frames keep their contact flags when the clip is
re-expressed in other units, shrunk or grown, or resampled (see
``tests/test_contact_scaling.py``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import jaxstyle as js
from jaxstyle.labels import contacts
from jaxstyle.motion import transform

SETS = {"100STYLE (60 fps)": "100style/*/*.bvh", "100STYLE skeleton, 30 fps run": "misc/*.bvh",
        "Xia (CMU skeleton, 120 fps)": "xia/*_0*.bvh", "PFNN excerpt (CMU skeleton, 120 fps)": "pfnn_excerpt/*.bvh"}
CLIPS = ("100style/Elated/Elated_FW.bvh", "xia/neutral_01_000.bvh", "pfnn_excerpt/NewCaptures01_000.bvh")


def stance_table(mocap: Path) -> None:
    print("| set | clips | paper2022: median (min-max) | scaled: median (min-max) |")
    print("|---|---|---|---|")
    for name, pattern in SETS.items():
        fractions = {rule: [] for rule in contacts.CONTACT_RULES}
        files = sorted(mocap.glob(pattern))
        for path in files:
            motion = js.read_bvh(path)
            for rule in contacts.CONTACT_RULES:
                fractions[rule].append(contacts.foot_contacts(motion, contacts.ContactConfig(rule=rule)).foot.mean())
        cells = [f"{np.median(f):.2f} ({min(f):.2f}-{max(f):.2f})" for f in
                 (fractions["paper2022"], fractions["scaled"])]
        print(f"| {name} | {len(files)} | {cells[0]} | {cells[1]} |")


def invariance_table(mocap: Path) -> None:
    print("\nFrames whose contact flags match the original's (nearest frame after resampling)")
    print("| clip | rule | x0.01 | x2.54 | x100 | x0.7 | x1.3 | 30 fps | 60 fps | 120 fps |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in CLIPS:
        motion = js.read_bvh(mocap / name)
        motion = motion.frames(0, 1200) if motion.num_frames > 1200 else motion
        for rule in contacts.CONTACT_RULES:
            config = contacts.ContactConfig(rule=rule)
            ref = contacts.foot_contacts(motion, config).foot
            cells = [f"{(contacts.foot_contacts(transform.scale(motion, s), config).foot == ref).mean():.3f}"
                     for s in (0.01, 2.54, 100.0, 0.7, 1.3)]
            for fps in (30.0, 60.0, 120.0):
                if fps == motion.fps:
                    cells.append("-")
                    continue
                m = transform.resample(motion, fps)
                near = np.minimum(np.round(np.arange(m.num_frames) * motion.fps / fps).astype(int),
                                  motion.num_frames - 1)
                cells.append(f"{(contacts.foot_contacts(m, config).foot == ref[near]).mean():.3f}")
            print(f"| {name} | {rule} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mocap", type=Path, default=None, help="motion capture folder (default $JAXSTYLE_MOCAP)")
    args = parser.parse_args()
    mocap = args.mocap or js.mocap_dir()
    stance_table(mocap)
    invariance_table(mocap)


if __name__ == "__main__":
    main()
