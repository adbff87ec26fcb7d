"""Checkpoints over orbax-checkpoint, with the run's config saved beside the weights.

``Checkpointer(directory, config)`` writes ``config.json`` once (refusing a directory that holds
a different config, so two runs never mix) and keeps the last ``max_to_keep`` steps. Orbax
writes each step to a temporary folder and renames it when complete, so an interrupted save
leaves the previous checkpoint intact and :meth:`restore` resumes from the last complete one.

Guards (see ``docs/bad_input.md``):

* :meth:`Checkpointer.save` refuses a tree with a NaN or infinite value
  (:class:`NonFiniteError`): a checkpoint never holds NaN weights.
* :meth:`Checkpointer.restore` (latest step) checks each step, newest first, and falls back to the
  newest good one with a warning ``checkpoint step N in PATH is damaged (...); using step M`` (a
  truncated data file, an emptied ``_METADATA``, an empty step folder, NaN values); when no step
  is good it raises one :class:`CheckpointError` naming the folder.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
import time
import warnings
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

from jaxstyle.errors import JaxstyleError


class CheckpointError(JaxstyleError):
    """A checkpoint folder with no usable step (every step damaged), or a damaged step asked for."""


class CheckpointMismatchError(CheckpointError):
    """A readable checkpoint of another model: its arrays have other shapes (or names) than the
    model restoring it (an adapter of a base of other sizes, say). Not damage: nothing is set aside."""


def _mismatch(state: Any, like: Any) -> str | None:
    """How ``state`` (restored) differs from ``like`` in names or shapes, or None."""
    saved, _ = jax.tree_util.tree_flatten_with_path(state)
    wanted, _ = jax.tree_util.tree_flatten_with_path(like)
    saved_names = [jax.tree_util.keystr(k) for k, _ in saved]
    wanted_names = [jax.tree_util.keystr(k) for k, _ in wanted]
    if saved_names != wanted_names:
        extra = sorted(set(saved_names) - set(wanted_names))[:3]
        missing = sorted(set(wanted_names) - set(saved_names))[:3]
        return f"other arrays (saved but not in this model: {extra or 'none'}; missing: {missing or 'none'})"
    for name, (_, a), (_, b) in zip(saved_names, saved, wanted, strict=True):
        if np.shape(a) != np.shape(b):
            return f"{name} is {tuple(np.shape(a))} there and {tuple(np.shape(b))} in this model"
    return None


class NonFiniteError(JaxstyleError, FloatingPointError):
    """Training produced NaN or infinity (a loss or a parameter); nothing is saved."""


def _jsonable(config: Any) -> Any:
    if dataclasses.is_dataclass(config):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(config).items()}
    if isinstance(config, dict):
        return {str(k): _jsonable(v) for k, v in config.items()}
    if isinstance(config, (tuple, list)):
        return [_jsonable(v) for v in config]
    if isinstance(config, Path):
        return str(config)
    return config


def finite_or_none(value: Any) -> Any:
    """``value`` with every NaN or infinite float (Python or NumPy, in dicts, lists and tuples)
    replaced by ``None`` and NumPy scalars turned into Python numbers, for strict JSON."""
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if isinstance(value, np.ndarray):
        return finite_or_none(value.tolist())
    if isinstance(value, (np.bool_, np.integer)):
        return value.item()
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def read_json(path: str | os.PathLike) -> Any:
    """The JSON value in the file at ``path``; a file that is not JSON (or not UTF-8) raises a
    ValueError whose message names the file and, where there is one, the line:
    ``PATH, line N: not valid JSON (reason)``."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        line = f", line {e.lineno}" if isinstance(e, json.JSONDecodeError) else ""
        raise ValueError(f"{path}{line}: not valid JSON ({getattr(e, 'msg', e)})") from None


def json_text(value: Any, **kwargs) -> str:
    """Strict JSON of ``value`` (``allow_nan=False``): a NaN or infinity, where a value may
    legitimately be missing (a loss of a style without validation rows), is written ``null``;
    every JSON file jaxstyle writes goes through this, so none holds a bare ``NaN``."""
    kwargs.setdefault("indent", 2)
    return json.dumps(finite_or_none(_jsonable(value)), allow_nan=False, **kwargs)


def saved_form(tree: Any) -> Any:
    """What is written for ``tree``: a training state held in a NamedTuple (e.g.
    :class:`jaxstyle.mason2018.train.BaseState`) as the dict of its fields, anything else as it is;
    so the files of a state are the same whichever container holds its arrays."""
    return tree._asdict() if isinstance(tree, tuple) and hasattr(tree, "_asdict") else tree


def non_finite_leaves(tree: Any) -> list[str]:
    """The key paths (``params/w``...) of the floating-point leaves of ``tree`` holding a NaN or
    an infinity."""
    bad = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        value = np.asarray(leaf)
        if np.issubdtype(value.dtype, np.inexact) and not np.isfinite(value).all():
            bad.append(jax.tree_util.keystr(path, simple=True, separator="/") or "(root)")
    return bad


def _reason(error: BaseException) -> str:
    """One line of an orbax / tensorstore error (their messages run to many lines)."""
    text = " ".join(str(error).split())
    text = f"{type(error).__name__}: {text}" if text else type(error).__name__
    return text if len(text) <= 200 else text[:197] + "..."


class Checkpointer:
    """Save and restore pytrees under ``directory``; ``config`` (a dataclass or dict) goes to
    ``directory/config.json``. ``restored_step`` is the step the last :meth:`restore` used."""

    def __init__(self, directory: str | os.PathLike, config: Any, max_to_keep: int = 3):
        self.directory = Path(directory).absolute()
        self.directory.mkdir(parents=True, exist_ok=True)
        config_json = _jsonable(config)
        path = self.directory / "config.json"
        if path.is_file():
            try:
                saved = json.loads(path.read_text())
            except json.JSONDecodeError as e:
                raise CheckpointError(f"{path} is not valid JSON ({e}); restore it or use a new directory") from None
            if saved != json.loads(json_text(config_json)):
                raise ValueError(f"{path} holds a different config; use a new directory for a new run")
        else:
            tmp = path.with_name("config.json.tmp")
            tmp.write_text(json_text(config_json, sort_keys=True))
            os.replace(tmp, path)
        self.steps_dir = self.directory / "steps"
        self._max_to_keep = max_to_keep
        self._manager = self._open()
        self.restored_step: int | None = None

    def _open(self):
        # each process reads and writes its checkpoints alone: under jax.distributed only process 0
        # writes (jaxstyle.train.shard.is_writer) and no other process takes part in its saves
        if jax.process_count() == 1:
            return ocp.CheckpointManager(self.steps_dir,
                                         options=ocp.CheckpointManagerOptions(max_to_keep=self._max_to_keep))
        me = jax.process_index()
        alone = ocp.options.MultiprocessingOptions(primary_host=me, active_processes={me},
                                                   barrier_sync_key_prefix=f"jaxstyle-process-{me}")
        self.steps_dir.mkdir(parents=True, exist_ok=True)  # orbax creates it only for all processes together
        return ocp.CheckpointManager(self.steps_dir, options=ocp.CheckpointManagerOptions(
            max_to_keep=self._max_to_keep, multiprocessing_options=alone, create=False))

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def all_steps(self) -> list[int]:
        return sorted(self._manager.all_steps())

    def save(self, step: int, state: Any, *, checked_finite: bool = False) -> None:
        """Save ``state`` as ``step``; a tree with NaN or infinity is refused (:class:`NonFiniteError`).
        ``checked_finite=True`` skips that scan for a caller that has just made it on this very tree
        (:func:`jaxstyle.train.scan.fit`), so a large state is not read twice per epoch."""
        state = saved_form(state)
        bad = [] if checked_finite else non_finite_leaves(state)
        if bad:
            raise NonFiniteError(f"refusing to save checkpoint step {step} in {self.steps_dir}: "
                                 f"{', '.join(bad[:5])}{' ...' if len(bad) > 5 else ''} hold NaN or infinity")
        if jax.process_count() > 1:  # arrays replicated over several processes' devices: this process's copy
            state = jax.tree.map(np.asarray, state)
        self._manager.save(step, args=ocp.args.StandardSave(state))
        self._manager.wait_until_finished()

    def _restore_step(self, like: Any, step: int) -> Any:
        """Step ``step`` restored and checked (in ``like``'s container), or a :class:`CheckpointError`
        saying what is wrong."""
        wanted = saved_form(like)
        folder = self.steps_dir / str(step)
        if folder.is_dir() and not any(folder.iterdir()):
            raise CheckpointError("the step folder is empty")
        if jax.process_count() > 1:  # restored on this process alone, as host arrays
            abstract = jax.tree.map(lambda v: np.zeros(np.shape(v), getattr(v, "dtype", np.float32)), wanted)
        else:
            abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, wanted)
        try:
            state = self._manager.restore(step, args=ocp.args.StandardRestore(abstract))
        except Exception as e:  # orbax/tensorstore raise many types for damaged files
            shapes = re.search(r"Requested shape: (\([^)]*\)) is not compatible with the stored shape: (\([^)]*\))",
                               str(e))
            if shapes:  # a readable checkpoint of another model
                raise CheckpointMismatchError(
                    f"checkpoint step {step} in {self.steps_dir} is of a model of other sizes: an array is "
                    f"{shapes.group(2)} there and {shapes.group(1)} in this model (written by another model, e.g. a "
                    "base of other sizes)") from None
            raise CheckpointError(_reason(e)) from e
        other = _mismatch(state, wanted)
        if other is not None:
            raise CheckpointMismatchError(f"checkpoint step {step} in {self.steps_dir} is of a model of other sizes: "
                                          f"{other} (written by another model, e.g. a base of other sizes)")
        bad = non_finite_leaves(state)
        if bad:
            raise CheckpointError(f"{', '.join(bad[:5])} hold NaN or infinity")
        return type(like)(**state) if wanted is not like else state

    def restore(self, like: Any, step: int | None = None) -> Any:
        """The state saved at ``step`` (default: the newest good step), with the structure of ``like``.

        Without ``step`` each saved step is tried, newest first; a damaged one (unreadable files,
        NaN values) gives a warning naming it and the step used instead. When no step is good,
        one :class:`CheckpointError` names the folder."""
        if step is not None:
            try:
                state = self._restore_step(like, step)
            except CheckpointMismatchError:
                raise
            except CheckpointError as e:
                raise CheckpointError(f"checkpoint step {step} in {self.steps_dir} is damaged ({e})") from e
            self.restored_step = step
            return state
        steps = self.all_steps()
        if not steps:
            raise FileNotFoundError(f"no checkpoint in {self.directory}")
        damaged = []
        for candidate in reversed(steps):
            try:
                state = self._restore_step(like, candidate)
            except CheckpointMismatchError:
                raise  # another model's checkpoint, not a damaged one
            except CheckpointError as e:
                damaged.append((candidate, str(e)))
                continue
            for bad_step, reason in damaged:
                warnings.warn(f"checkpoint step {bad_step} in {self.steps_dir} is damaged ({reason}); "
                              f"using step {candidate}", stacklevel=2)
            self.restored_step = candidate
            return state
        listing = "; ".join(f"step {s}: {r}" for s, r in damaged)
        raise CheckpointError(f"no usable checkpoint in {self.steps_dir}: every step is damaged ({listing}); "
                              "train into another run folder to start over")

    def set_aside_after(self, step: int) -> list[Path]:
        """Move the step folders after ``step`` (damaged ones a resumed run will write again) to
        ``directory/damaged/``; returns their new paths."""
        moved = []
        for s in self.all_steps():
            if s > step:
                target = self.directory / "damaged" / f"{s}-{time.strftime('%Y%m%d-%H%M%S')}"
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(self.steps_dir / str(s)), str(target))
                moved.append(target)
        if moved:
            self._manager.close()
            self._manager = self._open()
        return moved

    def close(self) -> None:
        self._manager.close()
