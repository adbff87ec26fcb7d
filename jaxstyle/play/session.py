"""The state of a live ``jaxstyle play`` session, free of any browser: the characters and how the
user steers them, one jitted step per displayed frame, style switches and blends, and the
recording buffer. The models it plays, and their styles, are :mod:`jaxstyle.play.models`'s.

Each frame the user's steering becomes one row of :class:`jaxstyle.control.loop.Controls` per
character (the desired ground displacement and facing at the six future samples, 0 .. 50 frames
ahead, and the PFNN demo's standing amount), and all characters advance by ONE frame in one
jitted call (``jit(vmap(step))`` over characters of the model's
:class:`jaxstyle.control.model.CharacterModel`, :func:`jaxstyle.control.model.batched_step_fn`, the
weights compiled in as constants, as :func:`jaxstyle.control.model.step_fn` does for one
character): the 2018 PFNN of Mason et al. 2018 section 7.1 (Holden et al. 2017's loop) or a 2022
style model (Mason, Starke & Komura 2022 section 4.4; the network gets the local phases it
carries, or for the PFNN backbone the global phase). Every style and blend has one shape per model
(:mod:`jaxstyle.play.models`), so a switch takes effect on the next frame without recompiling; the
PFNN backbone's per-style global-phase rate is carried in the state, so a switch replaces it there
(an array value, no recompile).

Units: the network works in the skeleton's file units; everything the user gives or sees here
(targets, speeds, positions) is in metres, metres per second and radians, Y up, a yaw ``a``
facing ``(sin a, cos a)`` in (x, z).
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import loop, lpn_controller
from jaxstyle.control.controller import Rollout, RolloutState
from jaxstyle.control.loop import stack_trees
from jaxstyle.data.pfnn_features import contact_columns
from jaxstyle.output import footlock
from jaxstyle.play import frame as live
from jaxstyle.play.frame import Steering, _wrap, control_rows
from jaxstyle.play.models import MAX_BLEND, AnyPlayModel, LPNPlayModel, PlayError, PlayModel, Style

STAND_EASE = 0.1  # per frame, the share of the gap to the asked standing amount closed (``Session.controls``)


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
        drawing = preview.Drawing(titles=[title or Path(path).stem], units_per_meter=model.units_per_meter)
        files.append(preview.render_gif(Path(path).with_suffix(".gif"), [global_positions(motion)],
                                        skeleton.parents, skeleton.fps, drawing, every=2))
    return files
