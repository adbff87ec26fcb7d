"""Which clips a dataset is built from: :class:`ClipSpec` (file, style, frame range, mirrored or
not) and the ``specs_*`` functions that make them for the layouts in use:

* :func:`specs_from_folder`: any folder, the style of each file from a mapping or a regular
  expression with a ``style`` group;
* :func:`specs_100style`: ``<root>/<Style>/<Style>_<GAIT>.bvh`` with ``Frame_Cuts.csv`` (start and
  stop frame of every style x gait; a stop beyond the file, as in the trimmed Neutral takes of
  the shared sample, is clipped to the file) and ``Dataset_List.csv`` (only styles flagged
  symmetric are also mirrored);
* :func:`specs_xia`: ``<style>_<content>_000.bvh``;
* :func:`specs_pfnn`: PFNN captures with their ``.phase`` labels (their ``_mirror`` files are
  separate captures, so nothing is mirrored again).

:mod:`jaxstyle.data.datasets` builds the rows of a list of them.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import re
from pathlib import Path
from typing import Mapping, Sequence

from jaxstyle.errors import MotionDataError
from jaxstyle.motion.skeleton import JointMap

GAITS_100STYLE = ("BR", "BW", "FR", "FW", "ID", "SR", "SW", "TR1", "TR2", "TR3")


@dataclasses.dataclass(frozen=True)
class ClipSpec:
    """One clip of a dataset: frames ``[start, stop)`` of ``path`` (at the file's rate), mirrored
    or not, labelled ``style``; ``phase_labels`` reads the PFNN ``.phase`` file for the phase;
    ``joint_map`` places the joints of a skeleton whose feet, hips, shoulders or hands are not found
    by name (:class:`jaxstyle.motion.skeleton.JointMap`; part of the cache key)."""

    path: str
    style: str
    start: int = 0
    stop: int | None = None
    mirror: bool = False
    gait: str = ""
    phase_labels: bool = False
    joint_map: JointMap | None = None

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("joint_map")
        if self.joint_map is not None:  # no key without a map: cache keys of other clips are unchanged
            d["joint_map"] = self.joint_map.to_json()
        return d

    @classmethod
    def from_json(cls, d: Mapping) -> "ClipSpec":
        d = dict(d)
        d["joint_map"] = JointMap.from_json(d.get("joint_map"))
        return cls(**d)


def with_joint_map(specs: Sequence[ClipSpec], joint_map: JointMap | None) -> list[ClipSpec]:
    """``specs`` with ``joint_map`` set on those that have none (``None``: unchanged)."""
    if joint_map is None:
        return list(specs)
    return [s if s.joint_map is not None else dataclasses.replace(s, joint_map=joint_map) for s in specs]


def specs_from_folder(folder: str | os.PathLike, *, styles: Mapping[str, str] | None = None,
                      pattern: str | None = None, mirror: bool = False,
                      joint_map: JointMap | None = None) -> list[ClipSpec]:
    """Clips of every ``*.bvh`` under ``folder``.

    Either ``styles`` maps a file name (or its stem) to a style, files it does not name being
    skipped, or ``pattern`` is a regular expression with a ``style`` group matched against the
    file stem. ``mirror`` adds a mirrored copy of each clip. ``joint_map`` (every ``specs_*``
    function takes one) goes on every clip (see :class:`ClipSpec`).
    """
    if (styles is None) == (pattern is None):
        raise ValueError("give exactly one of styles= or pattern=")
    folder = Path(folder)
    files = sorted(folder.rglob("*.bvh"))
    specs = []
    regex = re.compile(pattern) if pattern else None
    if regex is not None and "style" not in regex.groupindex:
        raise ValueError(f"pattern {pattern!r} has no (?P<style>...) group")
    for f in files:
        if styles is not None:
            style = styles.get(f.name, styles.get(f.stem))
        else:
            m = regex.fullmatch(f.stem)
            style = m.group("style") if m else None
        if style is None:
            continue
        specs += [ClipSpec(str(f), style)] + ([ClipSpec(str(f), style, mirror=True)] if mirror else [])
    if styles is not None:
        found = {s.style for s in specs}
        missing = sorted(set(styles.values()) - found)
        if missing:
            raise ValueError(f"styles {missing} name no file under {folder}")
    if not specs:
        raise ValueError(f"no BVH file under {folder} matches the style {'mapping' if styles else 'pattern'}")
    return with_joint_map(specs, joint_map)


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found (100STYLE layout needs it)")
    with open(path, newline="", encoding="utf-8-sig") as f:
        return list(csv.DictReader(f))


def symmetric_styles(path: str | os.PathLike) -> dict[str, bool]:
    """``{style: symmetric}`` from a 100STYLE ``Dataset_List.csv`` (columns ``Style Name`` and
    ``Symmetric``, Yes/No): which styles may be mirrored."""
    return {r["Style Name"]: r["Symmetric"].strip().lower() == "yes" for r in _read_csv(Path(path))}


def specs_100style(root: str | os.PathLike, *, styles: Sequence[str] | None = None,
                   gaits: Sequence[str] = GAITS_100STYLE, joint_map: JointMap | None = None) -> list[ClipSpec]:
    """Clips of a 100STYLE folder: every ``<Style>/<Style>_<GAIT>.bvh`` present, cut to its
    ``Frame_Cuts.csv`` range, mirrored too when ``Dataset_List.csv`` says the style is symmetric."""
    root = Path(root)
    cuts = {r["STYLE_NAME"]: r for r in _read_csv(root / "Frame_Cuts.csv")}
    symmetric = symmetric_styles(root / "Dataset_List.csv")
    wanted = set(styles) if styles is not None else None
    specs = []
    for style_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        style = style_dir.name
        if wanted is not None and style not in wanted:
            continue
        if style not in cuts:
            raise MotionDataError(f"style {style!r} is not in Frame_Cuts.csv", root / "Frame_Cuts.csv")
        for gait in gaits:
            path = style_dir / f"{style}_{gait}.bvh"
            start, stop = cuts[style].get(f"{gait}_START", "N/A"), cuts[style].get(f"{gait}_STOP", "N/A")
            if not path.is_file() or "N/A" in (start, stop):
                continue
            for mirror in (False, True) if symmetric.get(style, False) else (False,):
                specs.append(ClipSpec(str(path), style, int(start), int(stop), mirror, gait))
    if wanted is not None and (missing := sorted(wanted - {s.style for s in specs})):
        raise ValueError(f"styles {missing} have no clip under {root}")
    return with_joint_map(specs, joint_map)


def specs_xia(folder: str | os.PathLike, *, contents: Sequence[str] | None = None,
              mirror: bool = True, joint_map: JointMap | None = None) -> list[ClipSpec]:
    """Clips named ``<style>_<content>_000.bvh`` (Xia et al. 2015); mirrored too by default."""
    specs = specs_from_folder(folder, pattern=r"(?P<style>[a-z]+)_(?P<content>\d+)_\d+", mirror=mirror,
                              joint_map=joint_map)
    if contents is not None:
        specs = [s for s in specs if Path(s.path).stem.split("_")[1] in set(contents)]
    return specs


def specs_pfnn(folder: str | os.PathLike, style: str = "pfnn", joint_map: JointMap | None = None) -> list[ClipSpec]:
    """PFNN captures that have ``.phase`` labels; the phase comes from the labels."""
    files = sorted(p for p in Path(folder).glob("*.bvh") if p.with_suffix(".phase").is_file())
    if not files:
        raise ValueError(f"no BVH file with a .phase file in {folder}")
    return [ClipSpec(str(f), style, phase_labels=True, joint_map=joint_map) for f in files]
