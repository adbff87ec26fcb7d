"""The workflow behind the ``jaxstyle`` command: a data folder, a base PFNN, a few-shot sweep.

Mason et al. 2018 end to end, on any folder in the 100STYLE layout
(``<root>/<Style>/<Style>_<GAIT>.bvh`` with ``Frame_Cuts.csv`` and ``Dataset_List.csv``): the real
100STYLE archive (``jaxstyle data fetch 100style``), the shared sample, or the procedural styles of
:mod:`jaxstyle.data.procedural` (``jaxstyle data generate``, what ``jaxstyle demo`` trains on).

1. :func:`split_styles` picks the base (training) styles and the held-out few-shot styles;
2. :func:`train_base` trains (or resumes, or reloads) the base PFNN with one CP adapter per base
   style into a run folder, writing ``base.json`` (the :class:`BaseSettings`, so later commands
   rebuild the same data) and the normalisation statistics beside the checkpoints;
3. :func:`run_sweep` fine-tunes a new adapter for every (few-shot set, dropout rate) in one
   compiled program (:func:`jaxstyle.mason2018.selection.fewshot_sweep`) and writes the report (CSV,
   heatmap, chosen rates, adapters) and ``sweep.json`` (the sets' clips);
4. :func:`characters` gathers base and few-shot styles for :func:`jaxstyle.output.synthesis.synthesize`.

``experiments/fewshot_sweep.py`` is the same pipeline with the paper's settings on the shared
100STYLE sample.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import jax

from jaxstyle.data import datasets
from jaxstyle.data.datasets import ClipSpec
from jaxstyle.data.pfnn_features import PFNNLayout, valid_frames
from jaxstyle.errors import JaxstyleError
from jaxstyle.mason2018 import fewshot, selection
from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, train
from jaxstyle.motion import Motion
from jaxstyle.motion.bvh import frame_rate
from jaxstyle.nn import pfnn
from jaxstyle.output import synthesis
from jaxstyle.output.synthesis import Character

PAPER_FEWSHOT = ("Aeroplane", "Elated", "Rushed")
"""The held-out styles of ``experiments/fewshot_sweep.py`` (in the shared 100STYLE sample)."""
DEMO_FEWSHOT = ("Limping", "Proud")
"""The held-out styles of the procedural data (:mod:`jaxstyle.data.procedural`)."""
LOCOMOTION_GAITS = ("BR", "BW", "FR", "FW", "SR", "SW")
"""100STYLE's locomotion gaits: all but idling (ID) and transitions (TR1-3)."""


class PipelineError(JaxstyleError):
    """A run folder or data folder that cannot be used as asked (the message says why and what to do)."""


# --- data ---------------------------------------------------------------------------------------

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


def available_styles(root: Path) -> tuple[str, ...]:
    """Styles of a 100STYLE-layout folder that have at least one BVH file."""
    return tuple(sorted(p.name for p in root.iterdir() if p.is_dir() and any(p.glob(f"{p.name}_*.bvh"))))


def split_styles(root: Path, fewshot_styles: Sequence[str] | None = None,
                 base_styles: Sequence[str] | None = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(base, few-shot)`` styles of ``root``. The few-shot ones default to the procedural data's
    :data:`DEMO_FEWSHOT` or the paper's :data:`PAPER_FEWSHOT` when the folder has them, else its last
    style; the base ones default to every other style."""
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


def _cut(spec: ClipSpec, seconds: float | None) -> ClipSpec:
    if seconds is None:
        return spec
    stop = spec.start + int(round(seconds * frame_rate(spec.path)))
    return dataclasses.replace(spec, stop=stop if spec.stop is None else min(spec.stop, stop))


def folder_specs(root: Path, styles: Sequence[str], gaits: Sequence[str] | None = None) -> list[ClipSpec]:
    """Whole-file clips of ``<root>/<Style>/<Style>_<GAIT>.bvh`` for a folder without
    ``Frame_Cuts.csv``: every gait found unless ``gaits`` names some; each clip mirrored too unless
    ``Dataset_List.csv`` (100STYLE's columns ``Style Name``, ``Symmetric``) says the style is not
    symmetric."""
    listed = root / "Dataset_List.csv"
    symmetric = datasets.symmetric_styles(listed) if listed.is_file() else {}
    specs = []
    for style in styles:
        for f in sorted((root / style).glob(f"{style}_*.bvh")):
            gait = f.stem[len(style) + 1:]
            if gaits is not None and gait not in gaits:
                continue
            for mirror in (False, True) if symmetric.get(style, True) else (False,):
                specs.append(ClipSpec(str(f), style, mirror=mirror, gait=gait))
    missing = sorted(set(styles) - {s.style for s in specs})
    if missing:
        raise PipelineError(f"styles {missing} have no clip under {root}"
                            + (f" (gaits {', '.join(gaits)})" if gaits else ""))
    return specs


def clip_specs(root: Path, styles: Sequence[str], gaits: Sequence[str] | None = None,
               max_seconds: float | None = None) -> list[ClipSpec]:
    """Clips of ``styles`` and ``gaits``, each cut to its first ``max_seconds`` (default: the whole
    Frame_Cuts range, or the whole file); mirrored where the style is symmetric. With
    ``Frame_Cuts.csv`` (the 100STYLE layout) ``gaits`` defaults to :data:`LOCOMOTION_GAITS`, without
    it to every gait found (:func:`folder_specs`)."""
    if not (root / "Frame_Cuts.csv").is_file():
        return [_cut(s, max_seconds) for s in folder_specs(root, styles, gaits)]
    gaits = tuple(gaits or LOCOMOTION_GAITS)
    try:
        specs = datasets.specs_100style(root, styles=styles, gaits=gaits)
    except ValueError as e:
        raise PipelineError(f"{e} (gaits {', '.join(gaits)})") from None
    return [_cut(s, max_seconds) for s in specs]


def fewshot_specs(root: Path, styles: Sequence[str], seconds: float,
                  gaits: Sequence[str] | None = None) -> list[ClipSpec]:
    """One few-shot set per style and gait, named ``<Style>_<GAIT>``: ONE clip of ``seconds`` (plus
    the trajectory window the rows need) and its mirror for symmetric styles (2018 section 7)."""
    if seconds <= 0:
        raise PipelineError(f"few-shot seconds must be positive, got {seconds:g}")
    specs = []
    for spec in clip_specs(root, styles, gaits):
        fps = frame_rate(spec.path)
        n = int(round(10 * fps))
        window = n - len(valid_frames(n, fps))  # frames the trajectory window costs a clip
        stop = spec.start + int(round(seconds * fps)) + window
        specs.append(dataclasses.replace(spec, style=f"{spec.style}_{spec.gait}",
                                         stop=stop if spec.stop is None else min(spec.stop, stop)))
    return specs


def user_clip_specs(clips: Sequence[str | os.PathLike], mirror: bool,
                    seconds: tuple[float, float] | None = None) -> list[ClipSpec]:
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
        specs += [ClipSpec(str(path), path.stem, start, stop, mirror=m) for m in copies]
    return specs


def build(specs: Sequence[ClipSpec], cache: str | os.PathLike | None, progress: bool = False) -> datasets.Dataset:
    """PFNN rows of the clips (cached), clips too short for the trajectory window skipped."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # short clips are skipped with a warning
        return datasets.build_pfnn_dataset(specs, cache_dir=cache, skip_short=True, progress=progress)


# --- the base model -----------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class BaseSettings:
    """What a base model was trained on and how: the style folder ``data`` (:func:`style_root`), its
    ``styles`` and ``gaits`` (``None``: the default of :func:`clip_specs`; clips cut to
    ``max_seconds`` if set), the network's ``hidden`` size, the CP
    adapters' ``rank``, ``epochs`` (paper: 25, batch 32, Adam 1e-4, dropout 0.3) and ``seed``."""

    data: str
    styles: tuple[str, ...]
    gaits: tuple[str, ...] | None = None
    hidden: int = 512
    rank: int = 30
    epochs: int = 20
    max_seconds: float | None = None
    seed: int = 0

    def __post_init__(self):
        for name in ("hidden", "rank", "epochs"):
            if getattr(self, name) < 1:
                raise PipelineError(f"{name} must be positive, got {getattr(self, name)}")
        if self.max_seconds is not None and self.max_seconds <= 0:
            raise PipelineError(f"max_seconds must be positive, got {self.max_seconds}")

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, d: dict) -> "BaseSettings":
        d = dict(d)
        d["styles"] = tuple(d["styles"])
        d["gaits"] = None if d.get("gaits") is None else tuple(d["gaits"])
        return cls(**d)


class Base(NamedTuple):
    """A trained base: shared ``params``, the base styles' ``adapters`` (stacked in the order of
    ``dataset.styles``), the (input, output) ``normalisers``, the ``model`` config, the training
    ``dataset``, a clip of the ``skeleton`` and the :class:`BaseSettings`."""

    params: dict
    adapters: dict
    normalisers: tuple
    model: pfnn.PFNNConfig
    dataset: datasets.Dataset
    skeleton: Motion
    settings: BaseSettings


def _settings_file(directory: Path) -> Path:
    return directory / "base.json"


def train_base(settings: BaseSettings, directory: str | os.PathLike, *, cache: str | os.PathLike | None = None,
               progress: bool = True, log: Callable[[str], None] = print) -> Base:
    """Train the base into ``directory`` (resuming a partial run there; a finished one is only
    loaded). A folder holding a base trained with other settings is refused."""
    directory = Path(directory)
    path = _settings_file(directory)
    if path.is_file():
        old = BaseSettings.from_json(json.loads(path.read_text()))
        if old != settings:
            changed = [f.name for f in dataclasses.fields(settings)
                       if getattr(old, f.name) != getattr(settings, f.name)]
            raise PipelineError(f"{directory} holds a base trained with other settings ({', '.join(changed)} differ); "
                                "use another --run folder or delete that one")
    root = Path(settings.data)
    dataset = build(clip_specs(root, settings.styles, settings.gaits, settings.max_seconds), cache, progress)
    data = data_from_dataset(dataset)
    layout = PFNNLayout((dataset.inputs.shape[1] - 48) // 6)
    model = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size,
                            hidden_size=settings.hidden, rank=settings.rank)
    config = TrainConfig(model=model, epochs=settings.epochs, half_mirrored=True, seed=settings.seed)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(settings.to_json(), indent=2))
    os.replace(tmp, path)
    x_norm, y_norm = dataset.normalisers()
    x_norm.save(directory / "input_norm.npz")
    y_norm.save(directory / "output_norm.npz")
    log(f"base: {len(dataset.styles)} styles ({', '.join(dataset.styles)}), {len(dataset.specs)} clips, "
        f"{sum(map(len, data.train_rows)):,} training rows; PFNN {model.input_size} -> {model.hidden_size} -> "
        f"{model.output_size}, CP adapters of rank {model.rank}; {settings.epochs} epochs")
    state = train(data, config, directory, progress=progress)
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    return Base(state["params"], state["adapters"], (x_norm, y_norm), model, dataset, skeleton, settings)


def load_base(directory: str | os.PathLike, *, cache: str | os.PathLike | None = None, progress: bool = True,
              log: Callable[[str], None] = print) -> Base:
    """The base trained into ``directory`` by :func:`train_base` (finishing its training if it was
    interrupted)."""
    directory = Path(directory)
    path = _settings_file(directory)
    if not path.is_file():
        raise PipelineError(f"no base model in {directory} (no base.json): train one first with "
                            "`jaxstyle train-base --data PATH --run RUN` (or `jaxstyle demo`)")
    settings = BaseSettings.from_json(json.loads(path.read_text()))
    if not Path(settings.data).is_dir():
        raise PipelineError(f"the base in {directory} was trained on {settings.data}, which is gone")
    return train_base(settings, directory, cache=cache, progress=progress, log=log)


# --- few-shot sweep -----------------------------------------------------------------------------

def run_sweep(base: Base, specs: Sequence[ClipSpec], directory: str | os.PathLike, *,
              rates: Sequence[float] = (0.3, 0.5, 0.7), epochs: int = 100, adapter_dropout_only: bool = False,
              cache: str | os.PathLike | None = None, progress: bool = True
              ) -> tuple[selection.SweepResult, dict[str, Path], datasets.Dataset]:
    """Fine-tune a new adapter per (few-shot set of ``specs``, rate) on the frozen base in one compiled
    sweep, validate and check them closed-loop, choose a rate per set, and write the report to
    ``directory`` with ``sweep.json`` (the sets' clips). Returns the result, the report's paths and
    the few-shot dataset."""
    if not specs:
        raise PipelineError("no few-shot clips")
    if epochs < 1 or not rates or any(not 0 <= r < 1 for r in rates):
        raise PipelineError(f"need epochs >= 1 and dropout rates in [0, 1), got {epochs} and {list(rates)}")
    shots = build(specs, cache)
    if shots.inputs.shape[1] != base.model.input_size:
        raise PipelineError(f"the few-shot clips give {shots.inputs.shape[1]} inputs but the base takes "
                            f"{base.model.input_size}: they need the base's skeleton ({base.skeleton.num_joints} "
                            "joints)")
    config = fewshot.SweepConfig(model=base.model, epochs=epochs, rates=tuple(float(r) for r in rates),
                                 adapter_dropout_only=adapter_dropout_only)
    result = selection.fewshot_sweep(base.params, base.normalisers, shots, base.skeleton, config, progress=progress)
    paths = selection.write_report(result, directory, config)
    meta = {"specs": [dataclasses.asdict(s) for s in specs], "rates": list(config.rates), "epochs": epochs,
            "styles": list(result.styles), "seconds": result.seconds}
    path = Path(directory) / "sweep.json"
    path.with_name("sweep.json.tmp").write_text(json.dumps(meta, indent=2))
    os.replace(path.with_name("sweep.json.tmp"), path)
    paths["sweep"] = path
    return result, paths, shots


def sweep_table(result: selection.SweepResult) -> list[str]:
    """Markdown lines: per set, its rows, validation loss per rate, the chosen rate and its check."""
    lines = ["| set | train rows | " + " | ".join(f"val @ {r:g}" for r in result.rates) + " | chosen | check |",
             "|---|---|" + "---|" * len(result.rates) + "---|---|"]
    for s, style in enumerate(result.styles):
        cells = [f"{result.validation_loss[s, r]:.3f}" + ("" if result.rollout["passed"][s, r] else " (fails)")
                 for r in range(len(result.rates))]
        lines.append(f"| {style} | {result.train_rows[s]} | " + " | ".join(cells)
                     + f" | {result.chosen_rate(style):g} | {'passed' if result.chosen_passed[s] else 'FAILED'} |")
    return lines


def load_sweep(directory: str | os.PathLike, base: Base, *, cache: str | os.PathLike | None = None
               ) -> tuple[dict, datasets.Dataset]:
    """``(chosen rates, few-shot dataset)`` of a sweep written by :func:`run_sweep`."""
    directory = Path(directory)
    for name in ("sweep.json", "chosen_rates.json"):
        if not (directory / name).is_file():
            raise PipelineError(f"no few-shot sweep in {directory} (no {name}): run `jaxstyle sweep --run RUN` first")
    meta = json.loads((directory / "sweep.json").read_text())
    shots = build([ClipSpec(**s) for s in meta["specs"]], cache)
    return json.loads((directory / "chosen_rates.json").read_text()), shots


def characters(base: Base, sweep_dir: str | os.PathLike | None, shots: datasets.Dataset | None, chosen: dict | None,
               *, base_styles: Sequence[str] = (), fewshot_sets: Sequence[str] = (), blend: bool = False
               ) -> list[Character]:
    """:class:`~jaxstyle.output.synthesis.Character` s: base styles (the base network with that style's
    adapter), few-shot sets (their chosen adapters from ``sweep_dir``), and with ``blend`` a 50/50
    blend of the first two few-shot sets (:func:`jaxstyle.output.synthesis.blend_character`)."""
    out = []
    for style in base_styles:
        if style not in base.dataset.styles:
            raise PipelineError(f"unknown base style {style!r}; the base has {', '.join(base.dataset.styles)}")
        s = base.dataset.styles.index(style)
        out.append(Character(f"{style} (base)", style, jax.tree.map(lambda v, s=s: v[s], base.adapters),
                             base.dataset, style))
    for name in fewshot_sets:
        if chosen is None or name not in chosen:
            raise PipelineError(f"unknown few-shot set {name!r}; the sweep has {', '.join(chosen or {}) or 'none'}")
        adapter = selection.load_adapter(Path(sweep_dir) / "adapters" / name, base.model)
        out.append(Character(f"{name} (few-shot, rate {chosen[name]['rate']:g})", name, adapter, shots, name))
    if blend:
        shot_chars = out[len(base_styles):]
        if len(shot_chars) < 2:
            raise PipelineError("a blend needs two few-shot sets")
        out.append(synthesis.blend_character(*shot_chars[:2]))
    return out
