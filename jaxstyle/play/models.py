"""The models a live ``jaxstyle play`` session plays, free of any browser: what a run folder holds
(:func:`available_models`), loading it (:func:`load_any`) with its playable styles, and what a
session needs of a model (:func:`batched_step`, :func:`start_state`, the style's conditioning and
blends).

A run folder may hold two models: the 2018 PFNN with its CP adapters (``RUN/base``,
:class:`PlayModel`: base styles, the few-shot sweep's chosen adapters, styles learned live) and a
trained 2022 style model (``RUN/lpn``, written by ``jaxstyle lpn`` or ``jaxstyle demo --model
lpn-film``; :class:`LPNPlayModel`: the training styles' FiLM vectors and the styles the FiLM sweep
fine-tuned). Both give their network as a :class:`jaxstyle.control.model.CharacterModel`
(:meth:`PlayModel.character_model`), so the session's step, start and blends are written once.

A 2- or 3-way blend of 2018 styles is the exact CP adapter of the summed rank
(:func:`jaxstyle.nn.pfnn.blend_adapters`); every adapter is zero-padded to ``3 r`` components
(:func:`jaxstyle.nn.pfnn.pad_rank`, which changes nothing it computes), so a switch to any style or
blend feeds the compiled step arrays of the same shapes. A 2022 blend is the weighted FiLM vector
(:func:`jaxstyle.nn.style_models.blend_styles`; a PFNN-backbone CP adapter padded as the 2018
ones). The PFNN backbone's global phase advances at a per-style rate
(:meth:`jaxstyle.control.lpn_controller.StyleNetModel.phase_ratio`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import batched_step_fn
from jaxstyle.data import folders
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import base_model, sweep_files
from jaxstyle.mason2022 import pipeline as pipeline2022
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.nn import pfnn
from jaxstyle.output.check import FAILED_MARK, failed_check

MAX_BLEND = 3
PLAY_DIR = "play"  # under the run folder: learned styles, uploads, recordings
PFNN = "pfnn"  # the model key of the 2018 PFNN (the 2022 models': jaxstyle.mason2022.synthesis.MODELS)
LPN_DIR = "lpn"  # under the run folder: the trained 2022 model (`jaxstyle lpn`, `jaxstyle demo --model lpn-film`)


class PlayError(folders.PipelineError):
    """Bad input to a play session (unknown style, bad blend, nothing recorded, ...), one line."""


@dataclasses.dataclass(frozen=True)
class Style:
    """A playable style: its ``name``, ``kind`` (``base``, ``few-shot``, ``learned``; a 2022
    model's ``base`` and ``fine-tuned``), the dropout ``rate`` the sweep chose for it (``None`` for
    base styles) and its style ``conditioning`` (what the model's step takes): the CP adapter
    (2018) or the FiLM vector ``(4 H,)`` (a 2022 FiLM model; a one-hot row or an adapter for the
    other 2022 models)."""

    name: str
    kind: str
    rate: float | None
    conditioning: Any

    @property
    def label(self) -> str:
        return self.name if self.rate is None else f"{self.name} ({self.kind}, rate {self.rate:g})"


@dataclasses.dataclass(kw_only=True)
class Playable:
    """What a :class:`jaxstyle.play.session.Session` needs of a model, written once for both
    (:class:`PlayModel`, :class:`LPNPlayModel`): its ``styles`` by name, the ``units_per_meter`` of
    its skeleton, the walking ``speed`` (m/s) of its first style and its ``run_dir``; each model
    gives its ``skeleton``, ``dataset`` (the training rows: start poses), its network as a
    :class:`jaxstyle.control.model.CharacterModel` (:meth:`character_model`) and :meth:`_padded`
    (one shape for every style and blend)."""

    styles: dict[str, Style]
    units_per_meter: float
    speed: float
    run_dir: Path
    refused: tuple[str, ...] = ()

    def character_model(self, blend_bias: float = 1.5):
        raise NotImplementedError

    def _padded(self, conditioning):
        return conditioning

    def batched_step(self, blend_bias: float = 1.5):
        """The jitted step of every character by one frame (:func:`batched_step`)."""
        return batched_step(self, blend_bias)

    def start_state(self):
        """The first style's training frame moving closest to the model's walking speed, standing at
        the origin (:func:`start_state`; a 2022 model's global-phase rate is set per character,
        :meth:`jaxstyle.play.session.Session.step`)."""
        return start_state(self)

    def runtime(self, styles: Sequence[Style], weights=None):
        """One character's conditioning: a style's (``weights`` ``None`` or one style) or the blend of
        1-3 styles with barycentric ``weights`` (:meth:`jaxstyle.control.model.CharacterModel.blend_styles`:
        the 2018 adapters' exact CP blend, the 2022 paper's section 4.4 weighted FiLM vectors), of
        one shape either way (:meth:`_padded`)."""
        if weights is None or len(styles) == 1:
            out = styles[0].conditioning
        else:
            out = self.character_model().blend_styles([s.conditioning for s in styles], weights)
        return self._padded(out)


@dataclasses.dataclass
class PlayModel(Playable):
    """A loaded run's 2018 model: the base (:class:`jaxstyle.mason2018.base_model.Base`) and its
    styles (:class:`Playable`). Styles learned live are added to it (:attr:`learnable`)."""

    base: base_model.Base
    key = PFNN
    title = "2018 PFNN"
    learnable = True

    @property
    def skeleton(self):
        return self.base.skeleton

    @property
    def dataset(self):
        return self.base.dataset

    def character_model(self, blend_bias: float = 1.5) -> PFNNModel:
        return self.base.character_model(blend_bias=blend_bias)

    def _padded(self, adapter):
        """Zero-padded to ``MAX_BLEND`` times the base's rank (:func:`jaxstyle.nn.pfnn.pad_rank`,
        which changes nothing the adapter computes)."""
        return pfnn.pad_rank(adapter, int(self.base.model.rank) * MAX_BLEND)


@dataclasses.dataclass
class LPNPlayModel(Playable):
    """A loaded run's 2022 style model: the reloaded model and data (:class:`jaxstyle.mason2022.
    synthesis.Loaded`) and its styles (:class:`Playable`; runtime styles: FiLM vectors for a FiLM
    model)."""

    loaded: synthesis2022.Loaded
    learnable = False

    @property
    def key(self) -> str:
        name = self.loaded.model.name
        return synthesis2022.model_key(name) if name in synthesis2022.MODELS.values() else name

    @property
    def title(self) -> str:
        return f"2022 {self.loaded.model.name}"

    @property
    def skeleton(self):
        return self.loaded.data.skeleton

    @property
    def dataset(self):
        return self.loaded.data.base

    @property
    def num_bones(self) -> int:
        """The LPN layout's bones: the skeleton's joints, then the hand end sites."""
        return LPNLayout.of_inputs(self.loaded.data.base.inputs.shape[1]).num_bones

    def character_model(self, blend_bias: float = 1.5) -> StyleNetModel:
        return self.loaded.character_model(blend_bias=blend_bias)

    def _padded(self, conditioning):
        """A PFNN-backbone CP adapter, whose exact blend has the summed rank, zero-padded to
        ``MAX_BLEND`` times its rank as the 2018 adapters are; FiLM vectors and one-hot rows keep
        their shape."""
        config = self.loaded.model.config
        if config.backbone == "pfnn" and config.modulation == "resad":
            return pfnn.pad_rank(conditioning, int(config.rank) * MAX_BLEND)
        return conditioning

    def phase_ratio(self, styles: Sequence[Style], weights=None) -> float:
        """The PFNN backbone's global-phase rate for a character playing ``styles`` (with
        ``weights``): :meth:`jaxstyle.control.lpn_controller.StyleNetModel.phase_ratio` of that
        runtime style on the training rows of its (heaviest) style, as
        :func:`jaxstyle.output.synthesis.synthesize` starts its characters. 1 for the LPN and MANN
        backbones, which do not read the global phase."""
        name = styles[0 if weights is None else int(np.argmax(weights))].name
        data = self.loaded.data
        ds = data.base if data.new is None or name in data.base.styles else data.new
        return self.character_model().phase_ratio(self.runtime(styles, weights), ds, name)


AnyPlayModel = PlayModel | LPNPlayModel


def _sweep_styles(directory: Path, base: base_model.Base, kind: str, allow_failed: bool = False
                  ) -> tuple[list[Style], list[str]]:
    """The chosen adapters of a sweep report written by :func:`jaxstyle.mason2018.pipeline.run_sweep`,
    and one line per set left out because it failed the closed-loop check at every rate
    (:func:`jaxstyle.output.check.failed_check`; kept, marked in its label, with ``allow_failed``)."""
    chosen_path = directory / "chosen_rates.json"
    if not chosen_path.is_file():
        return [], []
    chosen = sweep_files.read_chosen(chosen_path)
    styles, refused = [], []
    for name, info in chosen.items():
        if not (directory / "adapters" / name).is_dir():
            continue
        failed = failed_check(chosen[name], name)
        if failed and not allow_failed:
            refused.append(f"{failed}: not offered (jaxstyle play --allow-failed offers it)")
            continue
        adapter = sweep_files.load_adapter(directory / "adapters" / name, base.model)
        styles.append(Style(name, kind + (FAILED_MARK if failed else ""), float(info["rate"]), adapter))
    return styles, refused


def learned_root(run_dir: str | Path) -> Path:
    """Where styles learned live are kept: ``RUN/play/styles/<name>/`` (each a sweep report)."""
    return Path(run_dir) / PLAY_DIR / "styles"


def load_model(run_dir: str | Path, *, progress: bool = False, allow_failed: bool = False) -> PlayModel:
    """The base of ``RUN/base``, its base styles, the few-shot styles of ``RUN/sweep`` (their chosen
    rates) and the styles learned in earlier sessions (``RUN/play/styles``); a set that failed the
    closed-loop check at every rate is left out, one line in ``refused`` saying so, unless
    ``allow_failed``. A folder without a base raises :class:`jaxstyle.data.folders.PipelineError`
    naming it."""
    run_dir = Path(run_dir)
    base = base_model.load_base(run_dir / "base", cache=run_dir / "cache", progress=progress)
    styles: dict[str, Style] = {}
    for s, name in enumerate(base.dataset.styles):
        styles[name] = Style(name, "base", None, jax.tree.map(lambda v, s=s: v[s], base.adapters))
    found, refused = _sweep_styles(run_dir / "sweep", base, "few-shot", allow_failed)
    root = learned_root(run_dir)
    if root.is_dir():
        for d in sorted(p for p in root.iterdir() if p.is_dir()):
            more, left_out = _sweep_styles(d, base, "learned", allow_failed)
            found, refused = found + more, refused + left_out
    for style in found:
        styles[style.name] = style
    upm = estimate_units_per_meter(base.skeleton)
    rows = style_rows(base.dataset, base.dataset.styles[0])
    speed = PFNNModel.own_speed(base.dataset, rows, upm, base.skeleton.fps)
    return PlayModel(base, styles=styles, units_per_meter=upm, speed=speed, run_dir=run_dir, refused=tuple(refused))


def available_models(run_dir: str | Path) -> dict[str, str]:
    """The models a run folder holds, key -> label (the page's Model choice): ``pfnn`` for a 2018
    base (``RUN/base/base.json``) and the 2022 model's ``--model`` key (``lpn-film``, ...) for a
    trained 2022 model in ``RUN/lpn`` (its ``config.json`` and ``data.json``; read, not loaded)."""
    run_dir = Path(run_dir)
    out = {}
    if (run_dir / "base" / "base.json").is_file():
        out[PFNN] = "2018 PFNN (Mason et al. 2018)"
    folder = run_dir / LPN_DIR
    if (folder / "config.json").is_file() and (folder / "data.json").is_file():
        try:
            name = json.loads((folder / "data.json").read_text()).get("name", pipeline2022.MODEL)
        except (OSError, ValueError):
            name = pipeline2022.MODEL
        key = synthesis2022.model_key(name) if name in synthesis2022.MODELS.values() else name
        out[key] = f"2022 {name} (Mason et al. 2022)"
    return out


def load_lpn_model(run_dir: str | Path, *, progress: bool = False, runtime: dict | None = None) -> LPNPlayModel:
    """The trained 2022 model of ``RUN/lpn`` (:func:`jaxstyle.mason2022.synthesis.load_model`, its
    rows cached in ``RUN/cache``) with its styles (:func:`lpn_play_model`), driven with ``runtime``
    (``phase_floor``, ``foot_smooth`` and ``body_smooth`` of :class:`jaxstyle.mason2022.synthesis.Loaded`; default
    its defaults). A folder without one raises :class:`jaxstyle.data.folders.PipelineError` naming it."""
    run_dir = Path(run_dir)
    loaded = synthesis2022.load_model(run_dir / LPN_DIR, cache=run_dir / "cache", progress=progress)
    loaded = loaded._replace(**(runtime or {}))
    return lpn_play_model(loaded, run_dir)


def lpn_play_model(loaded: synthesis2022.Loaded, run_dir: str | Path | None = None) -> LPNPlayModel:
    """A reloaded 2022 model's styles: every training style as its runtime style (a FiLM model:
    the mean FiLM vector of the style's training clips), and the new styles fine-tuned by the FiLM
    sweep at their chosen rate when the model's folder has ``finetuned_generators.npz`` and
    ``chosen_rates.json`` (:func:`jaxstyle.mason2022.synthesis.characters`)."""
    model, data = loaded.model, loaded.data
    styles: dict[str, Style] = {}
    for c in synthesis2022.characters(loaded, styles=list(model.data.styles)):
        styles[c.style] = Style(c.style, "base", None, jax.tree.map(jnp.asarray, c.conditioning))
    chosen_path = loaded.directory / "chosen_rates.json"
    if (model.config.modulation == "film" and data.new is not None and chosen_path.is_file()
            and (loaded.directory / "finetuned_generators.npz").is_file()):
        chosen = json.loads(chosen_path.read_text())
        names = [n for n in chosen if n in data.new.styles and n not in styles]
        if names:
            for c in synthesis2022.characters(loaded, new_styles=names):
                styles[c.style] = Style(c.style, "fine-tuned", float(chosen[c.style]["rate"]),
                                        jnp.asarray(c.conditioning))
    upm = estimate_units_per_meter(data.skeleton)
    rows = style_rows(data.base, data.base.styles[0])
    speed = StyleNetModel.own_speed(data.base, rows, upm, float(data.skeleton.fps))
    return LPNPlayModel(loaded, styles=styles, units_per_meter=upm, speed=speed,
                        run_dir=Path(run_dir if run_dir is not None else loaded.directory.parent))


def load_any(run_dir: str | Path, key: str | None = None, *, progress: bool = False,
             allow_failed: bool = False, runtime: dict | None = None) -> AnyPlayModel:
    """The model ``key`` of the run folder (:func:`available_models`; default: the 2018 model when
    there is one, else the 2022 one; ``allow_failed`` as :func:`load_model`; ``runtime`` as
    :func:`load_lpn_model`). A folder without it raises one line naming what it has."""
    run_dir = Path(run_dir)
    have = available_models(run_dir)
    if key is None:
        key = next(iter(have), PFNN)
    if key == PFNN:
        return load_model(run_dir, progress=progress, allow_failed=allow_failed)
    if key not in have:
        raise PlayError(f"{run_dir} has no trained {key} model (it has: {', '.join(have) or 'none'}); train one with "
                        f"`jaxstyle lpn --run {run_dir}` or `jaxstyle demo --model {key} --run {run_dir}`")
    return load_lpn_model(run_dir, progress=progress, runtime=runtime)


_STEPS: dict = {}


def batched_step(model: AnyPlayModel, blend_bias: float = 1.5):
    """The jitted ``f(styles, states, (offsets, yaw, stand)) -> (states, frames)`` advancing ``C``
    characters by one frame (:func:`jaxstyle.control.model.batched_step_fn` of the model's
    :class:`jaxstyle.control.model.CharacterModel`, every argument with a leading character axis;
    the weights compiled in as constants). One per network: a new session on the same model
    (another page, a reloaded run) compiles nothing again."""
    character = model.character_model(blend_bias)
    key = (id(character.params), blend_bias)
    if key not in _STEPS or _STEPS[key][0] is not character.params:
        _STEPS[key] = (character.params, batched_step_fn(character))
    return _STEPS[key][1]


def start_state(model: AnyPlayModel):
    """A character's start: the first style's training frame moving closest to the model's walking
    speed, standing at the origin (:meth:`jaxstyle.control.model.CharacterModel.initial_state`)."""
    ds = model.dataset
    rows = style_rows(ds, ds.styles[0])
    row = loop.start_row(ds.inputs, model.speed, units_per_meter=model.units_per_meter, rows=rows,
                         fps=float(model.skeleton.fps))
    return model.character_model().initial_state(ds, row)
