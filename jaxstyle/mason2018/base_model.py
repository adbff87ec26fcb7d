"""A base model of Mason et al. 2018 in a run folder: its data, training, and reading back.

:class:`BaseSettings` say what a base is trained on and how (written as ``base.json`` beside the
checkpoints, so later commands rebuild the same data); :func:`train_base` trains (or resumes, or
reloads) the base PFNN with one CP adapter per base style into a run folder, with the
normalisation statistics beside the checkpoints; :func:`load_base` reads a finished one without
training or writing; :class:`Base` is what both return (with :meth:`Base.character_model`, the
base as a :class:`jaxstyle.control.model.CharacterModel`); :func:`build` gives the PFNN rows of
clips, as the few-shot sweep (:mod:`jaxstyle.mason2018.pipeline`) builds them too.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import jax

from jaxstyle.control.controller import PFNNModel
from jaxstyle.data import clips, datasets
from jaxstyle.data.clips import ClipSpec
from jaxstyle.data.folders import PAPER_BASE, PipelineError, clip_specs, located_path, portable_path
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.mason2018.train import TrainConfig, data_from_dataset, load_trained, train, with_contacts
from jaxstyle.motion import Motion
from jaxstyle.motion.skeleton import JointMap
from jaxstyle.nn import pfnn
from jaxstyle.train.checkpoint import json_text


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
    adapters' ``rank``, ``epochs`` (paper: 25, batch 32, Adam 1e-4, dropout 0.3) and ``seed``;
    ``joint_map`` for a skeleton whose joints are not found by name (``--joint-map``)."""

    data: str
    styles: tuple[str, ...]
    gaits: tuple[str, ...] | None = None
    hidden: int = 512
    rank: int = 30
    epochs: int = 20
    max_seconds: float | None = None
    seed: int = 0
    joint_map: JointMap | None = None
    contacts: bool = False  # the 2018 layout's optional foot contact outputs (jaxstyle.data.pfnn_features)

    def __post_init__(self):
        for name in ("hidden", "rank", "epochs"):
            if getattr(self, name) < 1:
                raise PipelineError(f"{name} must be positive, got {getattr(self, name)}")
        if self.max_seconds is not None and self.max_seconds <= 0:
            raise PipelineError(f"max_seconds must be positive, got {self.max_seconds}")

    def to_json(self, directory: str | os.PathLike | None = None) -> dict:
        """The settings as JSON; with ``directory`` (where the JSON is written) ``data`` is
        written relative to it when it lies inside the run folder (``directory``'s parent), so the
        run folder can be copied or moved and used from any directory (:func:`portable_path`)."""
        d = dataclasses.asdict(self)
        d["joint_map"] = None if self.joint_map is None else self.joint_map.to_json()
        if directory is not None:
            d["data"] = portable_path(self.data, directory)
        return d

    @classmethod
    def from_json(cls, d: dict, directory: str | os.PathLike | None = None) -> "BaseSettings":
        """Settings read from JSON; with ``directory`` a relative ``data`` is found from there."""
        d = dict(d)
        d["joint_map"] = JointMap.from_json(d.get("joint_map"))
        d["styles"] = tuple(d["styles"])
        d["gaits"] = None if d.get("gaits") is None else tuple(d["gaits"])
        if directory is not None:
            d["data"] = located_path(d["data"], directory)
        return cls(**d)

    def resolved(self) -> "BaseSettings":
        """The same settings with ``data`` an absolute path."""
        return dataclasses.replace(self, data=str(Path(self.data).resolve()))


def paper_base_settings(mocap: str | os.PathLike, epochs: int = 20) -> BaseSettings:
    """``experiments/fewshot_sweep.py``'s base: the :data:`PAPER_BASE` styles of the shared 100STYLE
    sample in ``mocap``, every gait, the paper's sizes."""
    return BaseSettings(str(Path(mocap) / "100style"), PAPER_BASE, clips.GAITS_100STYLE, epochs=epochs)


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

    def adapter(self, style: str) -> dict:
        """The adapter of the base style ``style`` (one of ``dataset.styles``)."""
        if style not in self.dataset.styles:
            raise PipelineError(f"unknown base style {style!r}; the base has {', '.join(self.dataset.styles)}")
        s = self.dataset.styles.index(style)
        return jax.tree.map(lambda v: v[s], self.adapters)

    def character_model(self, *, blend_bias: float = 1.5) -> PFNNModel:
        """The base as a :class:`jaxstyle.control.model.CharacterModel`
        (:class:`jaxstyle.control.controller.PFNNModel`: a character's conditioning is its adapter)."""
        return PFNNModel.create(self.params, self.normalisers, self.skeleton.num_joints, blend_bias=blend_bias)


def _settings_file(directory: Path) -> Path:
    return directory / "base.json"


def train_base(settings: BaseSettings, directory: str | os.PathLike, *, cache: str | os.PathLike | None = None,
               progress: bool = True, log: Callable[[str], None] = print) -> Base:
    """Train the base into ``directory`` (resuming a partial run there; a finished one is only
    loaded). A folder holding a base trained with other settings is refused."""
    directory = Path(directory)
    settings = settings.resolved()
    path = _settings_file(directory)
    if path.is_file():
        old = BaseSettings.from_json(json.loads(path.read_text()), directory).resolved()
        if old != settings:
            changed = [f.name for f in dataclasses.fields(settings)
                       if getattr(old, f.name) != getattr(settings, f.name)]
            raise PipelineError(f"{directory} holds a base trained with other settings ({', '.join(changed)} differ); "
                                "use another --run folder or delete that one")
    dataset, data, model, config = _base_parts(settings, cache, progress)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json_text(settings.to_json(directory)))
    os.replace(tmp, path)
    x_norm, y_norm = dataset.normalisers()
    x_norm.save(directory / "input_norm.npz")
    y_norm.save(directory / "output_norm.npz")
    log(f"base: {len(dataset.styles)} styles ({', '.join(dataset.styles)}), {len(dataset.specs)} clips, "
        f"{sum(map(len, data.train_rows)):,} training rows; PFNN {model.input_size} -> {model.hidden_size} -> "
        f"{model.output_size}, CP adapters of rank {model.rank}; {settings.epochs} epochs")
    state = train(data, config, directory, progress=progress)
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    return Base(state.params, state.adapters, (x_norm, y_norm), model, dataset, skeleton, settings)


def _base_parts(settings: BaseSettings, cache, progress: bool):
    """The base's dataset, training arrays, network sizes and training config from its settings."""
    root = Path(settings.data)
    dataset = build(clip_specs(root, settings.styles, settings.gaits, settings.max_seconds, settings.joint_map), cache,
                    progress)
    if settings.contacts:
        dataset = with_contacts(dataset)
    data = data_from_dataset(dataset)
    layout = PFNNLayout((dataset.inputs.shape[1] - 48) // 6, contacts=settings.contacts)
    model = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size,
                            hidden_size=settings.hidden, rank=settings.rank)
    config = TrainConfig(model=model, epochs=settings.epochs, half_mirrored=True, seed=settings.seed)
    return dataset, data, model, config


def load_base(directory: str | os.PathLike, *, cache: str | os.PathLike | None = None, progress: bool = True
              ) -> Base:
    """The base trained into ``directory`` by :func:`train_base`, read only: nothing is trained or
    written there (the dataset cache, when given, may be filled). An unfinished base (an
    interrupted ``jaxstyle train-base``) is refused with the command that finishes it."""
    directory = Path(directory)
    path = _settings_file(directory)
    if not path.is_file():
        raise PipelineError(f"no base model in {directory} (no base.json): train one first with "
                            "`jaxstyle train-base --data PATH --run RUN` (or `jaxstyle demo`)")
    settings = BaseSettings.from_json(json.loads(path.read_text()), directory)
    if not Path(settings.data).is_dir():
        raise PipelineError(f"the base in {directory} was trained on {settings.data}, which is gone")
    dataset, _, model, config = _base_parts(settings, cache, progress)
    try:
        state = load_trained(config, dataset.styles, directory)
    except FileNotFoundError:
        state = None
    done = 0 if state is None else int(state.epoch)
    if done < settings.epochs:
        raise PipelineError(f"the base in {directory} is unfinished ({done} of {settings.epochs} epochs): finish it "
                            f"with `jaxstyle train-base --run {directory.parent}` and the same settings")
    x_norm, y_norm = dataset.normalisers()
    skeleton = datasets.load_clip(dataset.specs[0], fps=60.0)
    return Base(state.params, state.adapters, (x_norm, y_norm), model, dataset, skeleton, settings)
