"""Data-parallel training over all local (or, with ``jax.distributed``, all global) devices.

A 1-D :class:`jax.sharding.Mesh` with one axis ``"data"``: every minibatch's rows are split over
the devices (``PartitionSpec(None, "data")`` on a ``(steps, batch)`` plan), the parameters, the
optimiser state and the dataset arrays are replicated (``PartitionSpec()``). The jitted step is
the same function as on one device: XLA's SPMD partitioner splits the batch work and all-reduces
the gradient (the loss is a mean over the batch), so a sharded step equals the one-device step up
to the order of the float sums (``tests/test_lpn_sharded.py``). Random numbers are drawn with
JAX's partitionable threefry, so dropout masks do not depend on the device count.

Multi-host: start every process with the same command and ``--distributed`` (or call
:func:`initialize` first); :func:`jax.distributed.initialize` reads the coordinator from the
cluster environment (SLURM, Cloud TPU, or ``JAX_COORDINATOR_ADDRESS`` / ``JAX_NUM_PROCESSES`` /
``JAX_PROCESS_ID``). Every process loads the whole dataset and builds the same batch plan, so
host arrays are identical everywhere, as :func:`jax.device_put` onto a global sharding requires.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "data"


def initialize() -> None:
    """``jax.distributed.initialize()`` once (multi-host runs); later calls do nothing."""
    if not getattr(initialize, "done", False):
        jax.distributed.initialize()
        initialize.done = True


def data_mesh(devices: str | int | None = "all") -> Mesh | None:
    """The 1-D ``"data"`` mesh over ``"all"`` devices (every process's, after
    :func:`initialize`) or the first ``devices`` of them; ``None`` or ``1`` for no mesh (the plain
    one-device path)."""
    if devices is None:
        return None
    avail = jax.devices()
    n = len(avail) if devices == "all" else int(devices)
    if n < 1 or n > len(avail):
        raise ValueError(f"devices must be 'all' or 1..{len(avail)} (this machine has {len(avail)}), got {devices!r}")
    if n == 1:
        return None
    return Mesh(np.array(avail[:n]), (AXIS,))


def check_batch(mesh: Mesh | None, batch_size: int) -> None:
    """Each device gets the same number of rows: the batch must divide by the device count."""
    if mesh is not None and batch_size % mesh.size:
        raise ValueError(f"batch size {batch_size} does not divide over {mesh.size} devices; "
                         f"choose a multiple of {mesh.size}")


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, PartitionSpec())


def replicate(tree: Any, mesh: Mesh | None) -> Any:
    """Every array of ``tree`` on every device of ``mesh`` (unchanged without a mesh)."""
    if mesh is None:
        return tree
    return jax.device_put(tree, replicated(mesh))


def shard_batches(batches_TxB, mesh: Mesh | None):
    """``(steps, batch)`` row indices with the batch axis split over the mesh's devices."""
    if mesh is None:
        return jax.numpy.asarray(batches_TxB)
    check_batch(mesh, np.shape(batches_TxB)[1])
    return jax.device_put(np.asarray(batches_TxB), NamedSharding(mesh, PartitionSpec(None, AXIS)))
