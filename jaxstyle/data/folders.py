"""Style folders in the 100STYLE layout, shared by both papers' pipelines.

A style folder is ``<root>/<Style>/<Style>_<GAIT>.bvh``: the real 100STYLE archive (with its
``Frame_Cuts.csv`` and ``Dataset_List.csv``), the shared sample, the procedural styles of
:mod:`jaxstyle.data.procedural`, or your own files (whole files, no ``Frame_Cuts.csv``).
:func:`style_root` finds one, :func:`split_styles` picks the training and held-out styles and
:func:`clip_specs` lists their clips for :func:`jaxstyle.data.datasets.build_pfnn_dataset` or
:func:`jaxstyle.data.datasets.build_lpn_dataset`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Sequence

from jaxstyle.data import clips
from jaxstyle.data.clips import ClipSpec
from jaxstyle.errors import JaxstyleError
from jaxstyle.motion.bvh import frame_rate
from jaxstyle.motion.skeleton import JointMap

PAPER_FEWSHOT = ("Aeroplane", "Elated", "Rushed")
"""The held-out styles of ``experiments/fewshot_sweep.py`` (in the shared 100STYLE sample)."""
PAPER_BASE = ("Angry", "Chicken", "Drunk", "InTheDark", "Neutral")
"""The base styles of ``experiments/fewshot_sweep.py`` (the rest of the shared 100STYLE sample)."""
DEMO_FEWSHOT = ("Limping", "Proud")
"""The held-out styles of the procedural data (:mod:`jaxstyle.data.procedural`)."""
LOCOMOTION_GAITS = ("BR", "BW", "FR", "FW", "SR", "SW")
"""100STYLE's locomotion gaits: all but idling (ID) and transitions (TR1-3)."""


class PipelineError(JaxstyleError):
    """A run folder or data folder that cannot be used as asked (the message says why and what to do)."""


def style_root(path: str | os.PathLike) -> Path:
    """The style folder at ``path``: ``path`` itself or its ``100style``/``100STYLE`` sub-folder (so
    ``../shared/mocap`` works) when it holds ``Frame_Cuts.csv`` (the 100STYLE layout), else ``path``
    when it has style sub-folders of ``<Style>/<Style>_<GAIT>.bvh`` files (your own data: whole
    files, every one mirrored too unless a ``Dataset_List.csv`` says a style is not symmetric)."""
    path = Path(path).expanduser()
    if not path.is_dir():
        raise PipelineError(f"data folder {path} not found")
    for candidate in (path, path / "100style", path / "100STYLE"):
        if (candidate / "Frame_Cuts.csv").is_file():
            return candidate.resolve()
    if available_styles(path):
        return path.resolve()
    raise PipelineError(f"{path} holds no style folders: expected <root>/<Style>/<Style>_<GAIT>.bvh, as in 100STYLE "
                        f"(with its Frame_Cuts.csv, or without it to use whole files), or a 100style sub-folder; "
                        "`jaxstyle data generate` writes such a folder, `jaxstyle data fetch 100style` downloads one")


def available_styles(root: str | os.PathLike) -> tuple[str, ...]:
    """Styles of a 100STYLE-layout folder that have at least one BVH file."""
    root = Path(root)
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and any(p.glob(f"{p.name}_*.bvh"))))


def split_styles(root: str | os.PathLike, fewshot_styles: Sequence[str] | None = None,
                 base_styles: Sequence[str] | None = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(base, few-shot)`` styles of ``root``. The few-shot ones default to the procedural data's
    :data:`DEMO_FEWSHOT` or the paper's :data:`PAPER_FEWSHOT` when the folder has them, else its last
    style; the base ones default to every other style."""
    root = Path(root)
    have = available_styles(root)
    if not have:
        raise PipelineError(f"no <Style>/<Style>_<GAIT>.bvh file under {root}")
    for names, what in ((fewshot_styles, "few-shot"), (base_styles, "base")):
        unknown = sorted(set(names or ()) - set(have))
        if unknown:
            raise PipelineError(f"unknown {what} style(s) {', '.join(unknown)}; {root} has {', '.join(have)}")
    if fewshot_styles is None:
        fewshot_styles = tuple(s for s in DEMO_FEWSHOT if s in have) or tuple(s for s in PAPER_FEWSHOT if s in have)
        if not fewshot_styles or len(fewshot_styles) == len(have):
            fewshot_styles = have[-1:]
    if base_styles is None:
        base_styles = tuple(s for s in have if s not in fewshot_styles)
    both = sorted(set(base_styles) & set(fewshot_styles))
    if both:
        raise PipelineError(f"style(s) {', '.join(both)} are both base and few-shot styles")
    if not base_styles:
        raise PipelineError(f"no base style left: {root} has only {', '.join(have)}")
    return tuple(base_styles), tuple(fewshot_styles)


def cut(spec: ClipSpec, seconds: float | None) -> ClipSpec:
    """``spec`` cut to its first ``seconds`` (``None``: unchanged)."""
    if seconds is None:
        return spec
    stop = spec.start + int(round(seconds * frame_rate(spec.path)))
    return dataclasses.replace(spec, stop=stop if spec.stop is None else min(spec.stop, stop))


def folder_specs(root: str | os.PathLike, styles: Sequence[str], gaits: Sequence[str] | None = None,
                 joint_map: JointMap | None = None) -> list[ClipSpec]:
    """Whole-file clips of ``<root>/<Style>/<Style>_<GAIT>.bvh`` for a folder without
    ``Frame_Cuts.csv``: every gait found unless ``gaits`` names some; each clip mirrored too unless
    ``Dataset_List.csv`` (100STYLE's columns ``Style Name``, ``Symmetric``) says the style is not
    symmetric."""
    root = Path(root)
    listed = root / "Dataset_List.csv"
    symmetric = clips.symmetric_styles(listed) if listed.is_file() else {}
    specs = []
    for style in styles:
        for f in sorted((root / style).glob(f"{style}_*.bvh")):
            gait = f.stem[len(style) + 1:]
            if gaits is not None and gait not in gaits:
                continue
            for mirror in (False, True) if symmetric.get(style, True) else (False,):
                specs.append(ClipSpec(str(f), style, mirror=mirror, gait=gait, joint_map=joint_map))
    missing = sorted(set(styles) - {s.style for s in specs})
    if missing:
        raise PipelineError(f"styles {missing} have no clip under {root}"
                            + (f" (gaits {', '.join(gaits)})" if gaits else ""))
    return specs


def clip_specs(root: str | os.PathLike, styles: Sequence[str], gaits: Sequence[str] | None = None,
               max_seconds: float | None = None, joint_map: JointMap | None = None) -> list[ClipSpec]:
    """Clips of ``styles`` and ``gaits``, each cut to its first ``max_seconds`` (default: the whole
    Frame_Cuts range, or the whole file); mirrored where the style is symmetric. With
    ``Frame_Cuts.csv`` (the 100STYLE layout) ``gaits`` defaults to :data:`LOCOMOTION_GAITS`, without
    it to every gait found (:func:`folder_specs`). ``joint_map`` (``--joint-map``) goes on every
    clip, for skeletons whose joints are not found by name (:class:`jaxstyle.motion.skeleton.JointMap`)."""
    root = Path(root)
    if not (root / "Frame_Cuts.csv").is_file():
        return [cut(s, max_seconds) for s in folder_specs(root, styles, gaits, joint_map)]
    gaits = tuple(gaits or LOCOMOTION_GAITS)
    try:
        specs = clips.specs_100style(root, styles=styles, gaits=gaits, joint_map=joint_map)
    except ValueError as e:
        raise PipelineError(f"{e} (gaits {', '.join(gaits)})") from None
    return [cut(s, max_seconds) for s in specs]


def user_clip_specs(clips: Sequence[str | os.PathLike], mirror: bool,
                    seconds: tuple[float, float] | None = None, joint_map: JointMap | None = None) -> list[ClipSpec]:
    """One new style per user BVH file, named by the file's stem, and its mirror when ``mirror``;
    ``seconds`` = (start, end) keeps that range of each file."""
    if seconds is not None and not 0 <= seconds[0] < seconds[1]:
        raise PipelineError(f"clip range {seconds[0]:g} {seconds[1]:g}: need 0 <= START < END")
    paths = [Path(c) for c in clips]
    if len({p.stem for p in paths}) != len(paths):
        raise PipelineError("two clip files share a name; each file's stem names its style")
    specs = []
    for path in paths:
        if not path.is_file():
            raise PipelineError(f"clip {path}: no such file")
        start, stop = 0, None
        if seconds is not None:
            fps = frame_rate(path)
            start, stop = int(round(seconds[0] * fps)), int(round(seconds[1] * fps))
        copies = (False, True) if mirror else (False,)
        specs += [ClipSpec(str(path), path.stem, start, stop, mirror=m, joint_map=joint_map) for m in copies]
    return specs


def portable_path(path: str | os.PathLike, directory: str | os.PathLike) -> str:
    """How a run folder's JSON in ``directory`` records ``path``: relative to ``directory`` when
    ``path`` lies inside the run folder (``directory``'s parent), else absolute, so copying or
    moving the run folder, or using it from another working directory, keeps it valid."""
    path, directory = Path(path).resolve(), Path(directory).resolve()
    if directory.parent in path.parents:
        return os.path.relpath(path, directory)
    return str(path)


def located_path(recorded: str, directory: str | os.PathLike) -> str:
    """The path that :func:`portable_path` recorded in ``directory`` (a relative path found from
    ``directory``; a relative path of a run written before paths were recorded this way is read
    from the working directory, as it was written)."""
    if Path(recorded).is_absolute():
        return recorded
    here = Path(directory) / recorded
    if here.exists() or not Path(recorded).exists():
        return str(here.resolve())
    return str(Path(recorded).resolve())
