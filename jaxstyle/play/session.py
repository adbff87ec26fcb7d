"""The state of a live ``jaxstyle play`` session, free of any browser: the styles of a run folder,
the characters and how the user steers them, one jitted step per displayed frame, style switches
and blends, and the recording buffer.

A run folder may hold two models (:func:`available_models`): the 2018 PFNN with its CP adapters
(``RUN/base``, :class:`PlayModel`) and a trained 2022 style model (``RUN/lpn``, written by
``jaxstyle lpn`` or ``jaxstyle demo --model lpn-film``; :class:`LPNPlayModel`). A session plays one
of them; everything but the network step and the style's runtime form is shared.

The 2018 runtime is the PFNN controller of Mason et al. 2018 section 7.1 (Holden et al. 2017's loop,
:mod:`jaxstyle.control.controller`): each frame the user's steering becomes one row of
:class:`jaxstyle.control.loop.Controls` (the desired ground displacement and facing at the six
future samples, 0 .. 50 frames ahead), and all characters advance by ONE frame in one jitted call
(``jit(vmap(step))`` over characters, :func:`jaxstyle.control.model.batched_step_fn`, the base
weights compiled in as constants, as :func:`jaxstyle.control.model.step_fn` does for one
character).

Styles are CP adapters (base styles, the few-shot sweep's chosen adapters, styles learned live).
A 2- or 3-way blend is the exact CP adapter of the summed rank
(:func:`jaxstyle.nn.pfnn.blend_adapters`). Every adapter is zero-padded to ``3 r`` components
(:func:`jaxstyle.nn.pfnn.pad_rank`, which changes nothing it computes), so switching from one
style to any other or to a blend feeds the compiled step arrays of the same shapes: a switch takes
effect on the next frame without recompiling.

The 2022 runtime (Mason, Starke & Komura 2022 section 4.4) is the controller of
:mod:`jaxstyle.control.lpn_controller` (the same loop, the same :class:`Controls` rows with the
same standing amount, read as that controller reads it; the network gets the local phases it
carries, or for the PFNN backbone the global phase), ``jit(vmap(step))`` of
:meth:`jaxstyle.control.lpn_controller.StyleNetModel.step`, the weights compiled in as constants. Its styles
are FiLM vectors (the training styles' runtime vectors and the styles fine-tuned by the FiLM sweep,
:func:`jaxstyle.mason2022.synthesis.characters`; one-hot rows or adapters for the other Table 2
models); a blend is the weighted FiLM vector (:func:`jaxstyle.nn.style_models.blend_styles`,
linear and shape-preserving; a PFNN-backbone CP adapter padded as the 2018 ones), so a switch or a
blend again feeds arrays of the same shapes to the compiled step. The PFNN backbone's global phase
advances at a per-style rate (:func:`jaxstyle.control.lpn_controller.phase_ratio`), which the state
carries: a switch replaces the character's rate in its state (an array value, no recompile).

Units: the network works in the skeleton's file units; everything the user gives or sees here
(targets, speeds, positions) is in metres, metres per second and radians, Y up, a yaw ``a``
facing ``(sin a, cos a)`` in (x, z).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop, lpn_controller
from jaxstyle.control.controller import PFNNModel, Rollout, RolloutState
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import batched_step_fn, stack_trees
from jaxstyle.data.datasets import style_rows
from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.data.pfnn_features import contact_columns
from jaxstyle.labels.contacts import estimate_units_per_meter
from jaxstyle.mason2018 import pipeline, selection
from jaxstyle.mason2022 import synthesis as synthesis2022
from jaxstyle.nn import pfnn
from jaxstyle.output import footlock
from jaxstyle.play import frame as live
from jaxstyle.play.frame import Steering, _wrap, control_rows

MAX_BLEND = 3
STAND_EASE = 0.1  # per frame, the share of the gap to the asked standing amount closed (``Session.controls``)
PLAY_DIR = "play"  # under the run folder: learned styles, uploads, recordings
PFNN = "pfnn"  # the model key of the 2018 PFNN (the 2022 models': jaxstyle.mason2022.synthesis.MODELS)
LPN_DIR = "lpn"  # under the run folder: the trained 2022 model (`jaxstyle lpn`, `jaxstyle demo --model lpn-film`)


class PlayError(pipeline.PipelineError):
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


class PlayModel(NamedTuple):
    """A loaded run's 2018 model: the base (:class:`jaxstyle.mason2018.pipeline.Base`), its
    ``styles`` by name, the ``units_per_meter`` of its skeleton and the walking ``speed`` (m/s) of
    its first style. The methods are what a :class:`Session` needs of a model (shared with
    :class:`LPNPlayModel`)."""

    base: pipeline.Base
    styles: dict[str, Style]
    units_per_meter: float
    speed: float
    run_dir: Path

    @property
    def key(self) -> str:
        return PFNN

    @property
    def title(self) -> str:
        return "2018 PFNN"

    @property
    def skeleton(self):
        return self.base.skeleton

    @property
    def learnable(self) -> bool:
        """Whether a style can be learned live on this model (:mod:`jaxstyle.play.learn`)."""
        return True

    @property
    def dataset(self):
        """The training rows (start poses)."""
        return self.base.dataset

    def character_model(self, blend_bias: float = 1.5) -> PFNNModel:
        """The base as a :class:`jaxstyle.control.model.CharacterModel`."""
        return self.base.character_model(blend_bias=blend_bias)

    def batched_step(self, blend_bias: float = 1.5):
        return batched_step(self, blend_bias)

    def start_state(self) -> RolloutState:
        """The first style's training frame moving closest to its own speed, standing at the origin."""
        return start_state(self)

    def runtime(self, styles: Sequence[Style], weights=None) -> dict:
        """One character's adapter: a style's (``weights`` ``None``) or the exact CP blend of 1-3
        styles (:func:`jaxstyle.nn.pfnn.blend_adapters`), zero-padded to ``MAX_BLEND`` times the
        base's rank (:func:`jaxstyle.nn.pfnn.pad_rank`) so every style and blend has one shape."""
        if weights is None:
            adapter = styles[0].conditioning
        else:
            adapter = self.character_model().blend_styles([s.conditioning for s in styles], weights)
        return pfnn.pad_rank(adapter, int(self.base.model.rank) * MAX_BLEND)


class LPNPlayModel(NamedTuple):
    """A loaded run's 2022 style model: the reloaded model and data (:class:`jaxstyle.mason2022.
    synthesis.Loaded`), its ``styles`` by name (runtime styles: FiLM vectors for a FiLM model), the
    skeleton's ``units_per_meter``, the walking ``speed`` (m/s) of its first training style."""

    loaded: synthesis2022.Loaded
    styles: dict[str, Style]
    units_per_meter: float
    speed: float
    run_dir: Path

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
    def learnable(self) -> bool:
        return False

    @property
    def num_bones(self) -> int:
        """The LPN layout's bones: the skeleton's joints, then the hand end sites."""
        return LPNLayout.of_inputs(self.loaded.data.base.inputs.shape[1]).num_bones

    @property
    def dataset(self):
        """The training rows (start poses)."""
        return self.loaded.data.base

    def character_model(self, blend_bias: float = 1.5) -> StyleNetModel:
        """The model as a :class:`jaxstyle.control.model.CharacterModel`."""
        return self.loaded.character_model(blend_bias=blend_bias)

    def batched_step(self, blend_bias: float = 1.5):
        return batched_step(self, blend_bias)

    def start_state(self) -> lpn_controller.LPNState:
        """As :meth:`PlayModel.start_state`, with that frame's local phases (the global phase's
        rate is set per character, :meth:`Session.step`)."""
        return start_state(self)

    def runtime(self, styles: Sequence[Style], weights=None):
        """One character's runtime style: a style's (``weights`` ``None``) or the blend of 1-3
        styles with barycentric ``weights`` (section 4.4: for FiLM the weighted sum of the FiLM
        vectors, :func:`jaxstyle.nn.style_models.blend_styles`), of the same shape either way (a
        PFNN-backbone CP adapter, whose exact blend has the summed rank, zero-padded to
        ``MAX_BLEND`` times its rank as the 2018 adapters are)."""
        config = self.loaded.model.config
        if weights is None or len(styles) == 1:
            out = styles[0].conditioning
        else:
            out = self.character_model().blend_styles([s.conditioning for s in styles], weights)
        if config.backbone == "pfnn" and config.modulation == "resad":
            out = pfnn.pad_rank(out, int(config.rank) * MAX_BLEND)
        return out

    def phase_ratio(self, styles: Sequence[Style], weights=None) -> float:
        """The PFNN backbone's global-phase rate for a character playing ``styles`` (with
        ``weights``): :func:`jaxstyle.control.lpn_controller.phase_ratio` of that runtime style on
        the training rows of its (heaviest) style, as :func:`jaxstyle.output.synthesis.synthesize`
        starts its characters (:meth:`jaxstyle.control.lpn_controller.StyleNetModel.phase_ratio`).
        1 for the LPN and MANN backbones, which do not read the global phase."""
        name = styles[0 if weights is None else int(np.argmax(weights))].name
        data = self.loaded.data
        ds = data.base if data.new is None or name in data.base.styles else data.new
        return self.character_model().phase_ratio(self.runtime(styles, weights), ds, name)


AnyPlayModel = PlayModel | LPNPlayModel


def _sweep_styles(directory: Path, base: pipeline.Base, kind: str) -> list[Style]:
    """The chosen adapters of a sweep report written by :func:`jaxstyle.mason2018.pipeline.run_sweep`."""
    chosen_path = directory / "chosen_rates.json"
    if not chosen_path.is_file():
        return []
    chosen = selection.read_chosen(chosen_path)
    return [Style(name, kind, float(info["rate"]), selection.load_adapter(directory / "adapters" / name, base.model))
            for name, info in chosen.items() if (directory / "adapters" / name).is_dir()]


def learned_root(run_dir: str | Path) -> Path:
    """Where styles learned live are kept: ``RUN/play/styles/<name>/`` (each a sweep report)."""
    return Path(run_dir) / PLAY_DIR / "styles"


def load_model(run_dir: str | Path, *, progress: bool = False) -> PlayModel:
    """The base of ``RUN/base``, its base styles, the few-shot styles of ``RUN/sweep`` (their chosen
    rates) and the styles learned in earlier sessions (``RUN/play/styles``). A folder without a
    base raises :class:`jaxstyle.data.folders.PipelineError` naming it."""
    run_dir = Path(run_dir)
    base = pipeline.load_base(run_dir / "base", cache=run_dir / "cache", progress=progress)
    styles: dict[str, Style] = {}
    for s, name in enumerate(base.dataset.styles):
        styles[name] = Style(name, "base", None, jax.tree.map(lambda v, s=s: v[s], base.adapters))
    for style in _sweep_styles(run_dir / "sweep", base, "few-shot"):
        styles[style.name] = style
    root = learned_root(run_dir)
    if root.is_dir():
        for d in sorted(p for p in root.iterdir() if p.is_dir()):
            for style in _sweep_styles(d, base, "learned"):
                styles[style.name] = style
    upm = estimate_units_per_meter(base.skeleton)
    rows = style_rows(base.dataset, base.dataset.styles[0])
    speed = PFNNModel.own_speed(base.dataset, rows, upm, base.skeleton.fps)
    return PlayModel(base, styles, upm, speed, run_dir)


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
            name = json.loads((folder / "data.json").read_text()).get("name", synthesis2022.pipeline.MODEL)
        except (OSError, ValueError):
            name = synthesis2022.pipeline.MODEL
        key = synthesis2022.model_key(name) if name in synthesis2022.MODELS.values() else name
        out[key] = f"2022 {name} (Mason et al. 2022)"
    return out


def load_lpn_model(run_dir: str | Path, *, progress: bool = False) -> LPNPlayModel:
    """The trained 2022 model of ``RUN/lpn`` (:func:`jaxstyle.mason2022.synthesis.load_model`, its
    rows cached in ``RUN/cache``) with its styles (:func:`lpn_play_model`). A folder without one
    raises :class:`jaxstyle.data.folders.PipelineError` naming it."""
    run_dir = Path(run_dir)
    loaded = synthesis2022.load_model(run_dir / LPN_DIR, cache=run_dir / "cache", progress=progress)
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
    return LPNPlayModel(loaded, styles, upm, speed, Path(run_dir if run_dir is not None else loaded.directory.parent))


def load_any(run_dir: str | Path, key: str | None = None, *, progress: bool = False) -> AnyPlayModel:
    """The model ``key`` of the run folder (:func:`available_models`; default: the 2018 model when
    there is one, else the 2022 one). A folder without it raises one line naming what it has."""
    run_dir = Path(run_dir)
    have = available_models(run_dir)
    if key is None:
        key = next(iter(have), PFNN)
    if key == PFNN:
        return load_model(run_dir, progress=progress)
    if key not in have:
        raise PlayError(f"{run_dir} has no trained {key} model (it has: {', '.join(have) or 'none'}); train one with "
                        f"`jaxstyle lpn --run {run_dir}` or `jaxstyle demo --model {key} --run {run_dir}`")
    return load_lpn_model(run_dir, progress=progress)


KEY_HEADINGS = {"W": 0.0, "A": math.pi / 2, "S": math.pi, "D": -math.pi / 2}
"""Keyboard steering: the heading of each key relative to the camera's view direction (W walks away
from the camera, S towards it, A to the left, D to the right)."""


def key_heading(key: str, camera_yaw: float) -> float:
    """The world heading of a steering key (:data:`KEY_HEADINGS`; arrow keys as W A S D) for a
    camera looking along yaw ``camera_yaw`` (its view direction projected on the ground)."""
    arrows = {"ARROWUP": "W", "ARROWLEFT": "A", "ARROWDOWN": "S", "ARROWRIGHT": "D"}
    k = arrows.get(key.upper(), key.upper())
    if k not in KEY_HEADINGS:
        raise PlayError(f"unknown steering key {key!r}; use W A S D or the arrow keys")
    return _wrap(camera_yaw + KEY_HEADINGS[k])


@dataclasses.dataclass
class Character:
    """One walking character: its style (``style``; or ``blend``: ``(names, weights)``), steering,
    formation offset (metres, added to every target so characters do not meet), its standing
    amount and the session frame from which its slot's recorded frames are its own (``since``)."""

    style: str
    steering: Steering
    offset: np.ndarray
    blend: tuple[tuple[str, ...], tuple[float, ...]] | None = None
    stand: float = 0.0
    since: int = 0


class Frame(NamedTuple):
    """What the scene shows after a step, in metres: joint ``positions (C, J, 3)``, ground
    ``origin (C, 2)``, ``yaw (C,)``, the predicted future trajectory ``future (C, 6, 2)`` (x, z) and
    the step's wall time ``step_ms`` (the jitted call, its inputs and reading back its outputs)."""

    positions: np.ndarray
    origin: np.ndarray
    yaw: np.ndarray
    future: np.ndarray
    step_ms: float


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


class Session:
    """A live session on a :class:`PlayModel` (2018) or :class:`LPNPlayModel` (2022): characters,
    steering, styles, blends, recording.

    Thread safety: the server calls every method from its own threads; the caller serialises them
    (``jaxstyle.play.server`` holds one lock around each call), so nothing here locks.
    """

    def __init__(self, model: AnyPlayModel, *, style: str | None = None, record_seconds: float = 30.0,
                 blend_bias: float = 1.5, foot_lock: bool = True,
                 foot_lock_config: footlock.FootLockConfig | None = None):
        self.model = model
        self.num_joints = model.skeleton.num_joints
        self.fps = float(model.skeleton.fps)
        self.upm = float(model.units_per_meter)
        columns = (contact_columns(self.num_joints, int(model.base.model.output_size))
                   if isinstance(model, PlayModel) else None)
        # the whole frame (network step, foot lock, scene arrays) as one jitted call, compiled once
        # per slot count (jaxstyle.play.frame)
        self._step = live.frame_program(model.batched_step(float(blend_bias)), model.skeleton, self.num_joints,
                                        columns, foot_lock_config)
        self._start = model.start_state()
        self.capacity = max(1, int(round(record_seconds * self.fps)))
        self.speed = float(model.speed)
        self.characters: list[Character] = []
        self._slots = 0
        self._states: RolloutState | None = None  # (slots, ...): the characters, then spare copies of the start
        self._lock_states: footlock.LockState | None = None
        self._runtimes = None
        self._runtime_of: dict = {}  # runtime style per style or blend played
        self._ratios: dict = {}  # the PFNN backbone's global-phase rate per style or blend played
        self._dirty = True
        self._where: tuple[np.ndarray, np.ndarray] | None = None  # (origin (S, 2) m, yaw (S,)) after the last step
        self._history: list = []  # per frame: (frame number, the host copy of every slot's network output)
        self.frames = 0
        self.foot_lock = bool(foot_lock)
        if not model.styles:
            raise PlayError(f"{model.title} of {model.run_dir} has no styles to play")
        self.add_character(style or next(iter(model.styles)))
        # run the blend's small array operations once per blend size, so the first blend the user
        # asks for costs no compilation either
        one = next(iter(model.styles.values()))
        for k in range(2, MAX_BLEND + 1):
            model.runtime([one] * k, np.full(k, 1.0 / k))

    # --- styles -------------------------------------------------------------------------------
    @property
    def styles(self) -> dict[str, Style]:
        return self.model.styles

    def _check_style(self, name: str) -> Style:
        if name not in self.model.styles:
            raise PlayError(f"unknown style {name!r}; this run has {', '.join(self.model.styles)}")
        return self.model.styles[name]

    def add_style(self, style: Style) -> None:
        """Make ``style`` playable (a style learned live); it replaces one of the same name."""
        self.model.styles[style.name] = style
        self._runtime_of.clear()
        self._dirty = True

    def set_style(self, name: str, character: int = 0) -> None:
        """Switch ``character`` to the style ``name`` (from the next frame on)."""
        self._check_style(name)
        c = self.characters[character]
        c.style, c.blend = name, None
        self._dirty = True

    def set_blend(self, names: Sequence[str], weights: Sequence[float], character: int = 0) -> None:
        """Drive ``character`` with a blend of up to :data:`MAX_BLEND` styles; ``weights`` are
        non-negative and are normalised to sum to 1 (all zero is refused)."""
        names = tuple(names)
        if not 1 <= len(names) <= MAX_BLEND or len(set(names)) != len(names):
            raise PlayError(f"a blend takes 1 to {MAX_BLEND} different styles, got {list(names)}")
        for n in names:
            self._check_style(n)
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(names),) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise PlayError(f"blend weights must be {len(names)} non-negative numbers, not all zero; got {w.tolist()}")
        c = self.characters[character]
        c.blend = (names, tuple(float(x) for x in w / w.sum()))
        c.style = names[int(np.argmax(w))]
        self._dirty = True

    def describe(self, character: int = 0) -> tuple[str, str]:
        """The name of what ``character`` plays and its dropout rate(s), for the screen."""
        c = self.characters[character]
        if c.blend is None:
            s = self.model.styles[c.style]
            return s.name, "-" if s.rate is None else f"{s.rate:g}"
        names, w = c.blend
        rates = [self.model.styles[n].rate for n in names]
        return (" + ".join(f"{100 * wi:.0f}% {n}" for n, wi in zip(names, w, strict=True)),
                " / ".join("-" if r is None else f"{r:g}" for r in rates))

    def _playing(self, c: Character) -> tuple[list[Style], np.ndarray | None]:
        if c.blend is None:
            return [self.model.styles[c.style]], None
        names, w = c.blend
        return [self.model.styles[n] for n in names], np.asarray(w)

    def runtime_of(self, c: Character):
        """The character's runtime style as the step takes it: its style's or its blend's adapter
        padded to the session's fixed rank (2018), or FiLM vector (2022)."""
        return self.model.runtime(*self._playing(c))

    adapter_of = runtime_of  # the 2018 name

    @staticmethod
    def _key(c: Character):
        return c.style if c.blend is None else c.blend

    # --- characters ---------------------------------------------------------------------------
    def add_character(self, style: str | None = None) -> int:
        """A new character beside the others (1.2 m apart), in ``style`` (default the first's);
        returns its index. It takes the next slot; past the last slot the slots double (the frame
        program compiles once for the new slot count)."""
        style = style or self.characters[0].style
        self._check_style(style)
        i = len(self.characters)
        offset = np.array([1.2 * ((i + 1) // 2) * (1 if i % 2 else -1), 0.0])
        first = self.characters[0].steering if self.characters else Steering(speed=self.speed)
        points = [(x + offset[0], z + offset[1]) for x, z in first.waypoints]  # the first has offset 0
        start = self._start._replace(hist_xz=self._start.hist_xz + jnp.asarray(offset * self.upm, jnp.float32))
        if i:  # the new one starts beside the first character, where it stands now
            here = jnp.asarray(self.origin()[0] * self.upm, jnp.float32) - self._start.hist_xz[-1]
            start = start._replace(hist_xz=start.hist_xz + here)
        if i >= self._slots:
            slots = live.slots_for(i + 1)
            spare = jax.tree.map(lambda v: jnp.broadcast_to(v, (slots - self._slots,) + v.shape), self._start)
            self._states = spare if self._states is None else jax.tree.map(
                lambda a, b: jnp.concatenate([a, b]), self._states, spare)
            locks = live.init_lock_states(slots - self._slots)
            self._lock_states = locks if self._lock_states is None else jax.tree.map(
                lambda a, b: jnp.concatenate([a, b]), self._lock_states, locks)
            self._slots = slots
        self._states = jax.tree.map(lambda a, b: a.at[i].set(b), self._states, start)
        self._lock_states = jax.tree.map(lambda a, b: a.at[i].set(b), self._lock_states, footlock.init_state())
        self.characters.append(Character(style, dataclasses.replace(first, waypoints=points), offset,
                                         since=self.frames))
        self._where = None
        self._dirty = True
        return i

    def remove_character(self) -> None:
        """Remove the last character (the first one always stays); its slot stays, unused."""
        if len(self.characters) > 1:
            self.characters.pop()
            self._dirty = True

    def _ground(self) -> tuple[np.ndarray, np.ndarray]:
        if self._where is None:
            xz, yaw = jax.device_get((self._states.hist_xz[:, -1], self._states.hist_yaw[:, -1]))
            self._where = (np.asarray(xz) / self.upm, np.asarray(yaw))
        return self._where

    def origin(self) -> np.ndarray:
        """Where each character stands, ``(C, 2)`` x z in metres."""
        return self._ground()[0][:len(self.characters)].copy()

    def yaw(self) -> np.ndarray:
        return self._ground()[1][:len(self.characters)].copy()

    # --- steering -----------------------------------------------------------------------------
    def walk_to(self, x: float, z: float, *, append: bool = False) -> None:
        """Walk to the ground point ``(x, z)`` metres (each character to it plus its formation
        offset); ``append`` adds it as the next waypoint after those already set."""
        if not (math.isfinite(x) and math.isfinite(z)):
            raise PlayError(f"a target must be a finite point, got ({x}, {z})")
        for c in self.characters:
            point = (float(x + c.offset[0]), float(z + c.offset[1]))
            if append and c.steering.mode == "target":
                c.steering.waypoints.append(point)
            else:
                c.steering.waypoints = [point]
            c.steering.mode = "target"

    def walk_along(self, heading: float, speed: float | None = None) -> None:
        """Walk along the world heading (yaw, radians) until told otherwise."""
        for c in self.characters:
            c.steering.mode, c.steering.heading = "direction", float(heading)
            c.steering.waypoints = []
        if speed is not None:
            self.set_speed(speed)

    def key(self, key: str, camera_yaw: float, *, run: bool = False) -> None:
        """A steering key (W A S D or arrows, relative to the camera); ``run`` (shift) walks at twice
        the walking speed."""
        self.walk_along(key_heading(key, camera_yaw))
        for c in self.characters:
            c.steering.speed = self.speed * (2.0 if run else 1.0)

    def stop(self) -> None:
        for c in self.characters:
            c.steering.mode, c.steering.waypoints = "stop", []

    def set_speed(self, speed: float) -> None:
        if not (math.isfinite(speed) and 0 < speed <= 10):
            raise PlayError(f"speed must be in (0, 10] m/s, got {speed}")
        self.speed = float(speed)
        for c in self.characters:
            c.steering.speed = self.speed

    def targets(self) -> list[list[tuple[float, float]]]:
        return [list(c.steering.waypoints) for c in self.characters]

    # --- the frame ----------------------------------------------------------------------------
    def controls(self) -> loop.Controls:
        """This frame's :class:`Controls` rows, stacked over characters: ``offsets (C, 6, 2)``,
        ``yaw (C, 6)`` and ``stand (C,)`` (:func:`jaxstyle.play.frame.control_rows`), no path
        following (the targets are steered here).

        ``stand`` is the PFNN demo's standing amount (Holden et al. 2017; see
        :func:`jaxstyle.control.controller.advance`): it eases towards 1 while a character is told
        to stand and towards 0 while it walks, by :data:`STAND_EASE` of the gap per frame, so a
        stopped character stops instead of drifting on."""
        offsets, yaw = control_rows(self.origin(), self.yaw(), [c.steering for c in self.characters], self.upm)
        for c in self.characters:
            c.stand += STAND_EASE * (float(c.steering.mode == "stop") - c.stand)
        return loop.Controls(offsets.astype(np.float32), yaw.astype(np.float32),
                             stand=np.array([c.stand for c in self.characters], np.float32))

    def _restack(self) -> None:
        """The runtime style of every slot (the spare slots play the first character's), and for a
        PFNN-backbone 2022 model each slot's global-phase rate."""
        keys = [self._key(c) for c in self.characters]
        for c, k in zip(self.characters, keys, strict=True):
            if k not in self._runtime_of:
                self._runtime_of[k] = self.runtime_of(c)
        padded = keys + [keys[0]] * (self._slots - len(keys))
        self._runtimes = stack_trees([self._runtime_of[k] for k in padded])
        if isinstance(self.model, LPNPlayModel) and self.model.loaded.model.config.backbone == "pfnn":
            for c, k in zip(self.characters, keys, strict=True):
                if k not in self._ratios:
                    self._ratios[k] = self.model.phase_ratio(*self._playing(c))
            ratios = [self._ratios[k] for k in padded]
            self._states = self._states._replace(phase_ratio=jnp.asarray(ratios, jnp.float32))

    def step(self) -> Frame:
        """Advance every character by one frame (one jitted call: the network step of every slot,
        the feet locked while planted when :attr:`foot_lock` is on, :mod:`jaxstyle.output.footlock`)
        and return what to draw."""
        t0 = time.perf_counter()
        if self._dirty:
            self._restack()
            self._dirty = False
        n, spare = len(self.characters), self._slots - len(self.characters)
        controls = self.controls()
        offsets = np.concatenate([controls.offsets, np.zeros((spare,) + controls.offsets.shape[1:], np.float32)])
        yaw = np.concatenate([controls.yaw, np.zeros((spare,) + controls.yaw.shape[1:], np.float32)])
        stand = np.concatenate([controls.stand, np.ones(spare, np.float32)])
        self._states, self._lock_states, out = self._step(self._runtimes, self._states, self._lock_states,
                                                          (offsets, yaw, stand), np.bool_(self.foot_lock))
        out = jax.device_get(out)
        self._where = (np.asarray(out.origin) / self.upm, np.asarray(out.yaw))
        self._history.append((self.frames, out.out))
        if len(self._history) > self.capacity:
            del self._history[: len(self._history) - self.capacity]
        self.frames += 1
        ms = 1e3 * (time.perf_counter() - t0)
        return Frame(np.asarray(out.positions[:n]) / self.upm, self._where[0][:n], self._where[1][:n],
                     np.asarray(out.future[:n]) / self.upm, ms)

    def recording(self, seconds: float, character: int = 0) -> Rollout | lpn_controller.LPNRollout:
        """The last ``seconds`` of ``character`` as a :class:`Rollout` (2022: an
        :class:`~jaxstyle.control.lpn_controller.LPNRollout`; frames on the leading axis), ready
        for :mod:`jaxstyle.output.export`."""
        since = self.characters[character].since
        frames = [out for k, out in self._history if k >= since]
        n = min(len(frames), int(round(seconds * self.fps)))
        if n < 2:
            raise PlayError("nothing recorded yet: let the character walk a moment first")
        return jax.tree.map(lambda *v: np.stack([x[character] for x in v]), *frames[-n:])


def save_recording(rollout: Rollout | lpn_controller.LPNRollout, model: AnyPlayModel, path: str | Path, *,
                   foot_lock: bool = True, gif: bool = True, title: str = "") -> list[Path]:
    """Write a recorded :class:`Rollout` as ``<path>.bvh`` (feet locked while planted with
    ``foot_lock``, :func:`jaxstyle.output.export.lock_feet`), ``<path>.npz`` and, with ``gif``,
    ``<path>.gif`` of the exported skeleton (:func:`jaxstyle.output.preview.render_gif`); returns the files."""
    from jaxstyle.motion.kinematics import global_positions
    from jaxstyle.output import export, preview

    skeleton = model.skeleton
    motion = export.rollout_motion(rollout, skeleton)
    if foot_lock:
        motion = export.lock_feet(motion, rollout, skeleton=skeleton).motion
    files = list(export.save_rollout(path, rollout, skeleton, motion=motion).values())
    if gif:  # the exported skeleton, as the BVH holds it
        files.append(preview.render_gif(Path(path).with_suffix(".gif"), [global_positions(motion)],
                                        skeleton.parents, skeleton.fps, titles=[title or Path(path).stem],
                                        units_per_meter=model.units_per_meter, every=2))
    return files
