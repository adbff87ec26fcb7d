"""Checkpoints over orbax-checkpoint, with the run's config saved beside the weights.

``Checkpointer(directory, config)`` writes ``config.json`` once (refusing a directory that holds
a different config, so two runs never mix) and keeps the last ``max_to_keep`` steps. Orbax
writes each step to a temporary folder and renames it when complete, so an interrupted save
leaves the previous checkpoint intact and :meth:`restore` resumes from the last complete one.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import jax
import orbax.checkpoint as ocp


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


class Checkpointer:
    """Save and restore pytrees under ``directory``; ``config`` (a dataclass or dict) goes to
    ``directory/config.json``."""

    def __init__(self, directory: str | os.PathLike, config: Any, max_to_keep: int = 3):
        self.directory = Path(directory).absolute()
        self.directory.mkdir(parents=True, exist_ok=True)
        config_json = _jsonable(config)
        path = self.directory / "config.json"
        if path.is_file():
            saved = json.loads(path.read_text())
            if saved != json.loads(json.dumps(config_json)):
                raise ValueError(f"{path} holds a different config; use a new directory for a new run")
        else:
            tmp = path.with_name("config.json.tmp")
            tmp.write_text(json.dumps(config_json, indent=2, sort_keys=True))
            os.replace(tmp, path)
        self._manager = ocp.CheckpointManager(self.directory / "steps",
                                              options=ocp.CheckpointManagerOptions(max_to_keep=max_to_keep))

    def latest_step(self) -> int | None:
        return self._manager.latest_step()

    def save(self, step: int, state: Any) -> None:
        self._manager.save(step, args=ocp.args.StandardSave(state))
        self._manager.wait_until_finished()

    def restore(self, like: Any, step: int | None = None) -> Any:
        """The state saved at ``step`` (default: the latest), with the structure of ``like``."""
        step = self.latest_step() if step is None else step
        if step is None:
            raise FileNotFoundError(f"no checkpoint in {self.directory}")
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, like)
        return self._manager.restore(step, args=ocp.args.StandardRestore(abstract))

    def close(self) -> None:
        self._manager.close()
