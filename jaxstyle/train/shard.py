"""Data-parallel training over all local (or, with ``jax.distributed``, all global) devices.

A 1-D :class:`jax.sharding.Mesh` with one axis ``"data"``: every minibatch's rows are split over
the devices (``PartitionSpec(None, "data")`` on a ``(steps, batch)`` plan), the parameters, the
optimiser state and the dataset arrays are replicated (``PartitionSpec()``). The jitted step is
the same function as on one device: XLA's SPMD partitioner splits the batch work and all-reduces
the gradient (the loss is a mean over the batch), so a sharded step equals the one-device step up
to the order of the float sums (``tests/test_lpn_sharded.py``). Random numbers are drawn with
JAX's partitionable threefry, so dropout masks do not depend on the device count.

Multi-process (several hosts, or several processes on one): start every process with the same
command and ``--distributed`` (or call :func:`initialize` first; the coordinator, process count
and id come from flags, ``JAX_COORDINATOR_ADDRESS`` / ``JAX_NUM_PROCESSES`` / ``JAX_PROCESS_ID``,
or the cluster, e.g. SLURM; docs/scale.md). Every process loads the whole dataset and builds the
same batch plan, so host arrays are identical everywhere, as :func:`jax.device_put` onto a global
sharding requires; results spread over the processes' devices come back whole with
:func:`gather`, and only process 0 writes (:func:`is_writer`).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxstyle.errors import JaxstyleError

AXIS = "data"


ENV = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")
WATCH_S = 15.0  # a process whose beat (jaxstyle's own, once a second) stops this long is taken for dead
HEARTBEAT_S = 60  # jax.distributed's own heartbeat timeout: later than WATCH_S, so the clear message comes first


class DistributedError(JaxstyleError):
    """A multi-process start that cannot work (a bad address, count or id), one line."""


def initialize(coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None, *,
               watch_s: float | None = None, timeout_s: int = 120) -> None:
    """``jax.distributed.initialize`` once (later calls do nothing), before anything uses a device.

    The coordinator ``host:port`` (process 0 serves it), the process count and this process's id
    come from the arguments, else from ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and
    ``JAX_PROCESS_ID``, else from the cluster JAX detects (SLURM, Open MPI, Cloud TPU);
    ``timeout_s`` bounds the wait for every process to join.

    A process that dies would leave the others waiting in their next collective. So every process
    beats once a second in the coordinator's key-value store and watches the others' beats
    (:func:`_watch`, a daemon thread): when another process's beat stops for ``watch_s`` seconds
    without it having said it finished (:func:`finish`), or the coordinator is gone, this process
    prints one line saying so and exits with status 1 (``watch_s`` default: ``JAXSTYLE_WATCH_S``,
    else :data:`WATCH_S`). JAX's own heartbeat (which aborts with a stack trace) is set to
    :data:`HEARTBEAT_S`, later than ``watch_s``; the coordinator's own death is reported by JAX at
    once, in its words ("another task died")."""
    if getattr(initialize, "done", False):
        return
    env = {k: os.environ.get(k) for k in ENV}
    if watch_s is None:
        try:
            watch_s = float(os.environ.get("JAXSTYLE_WATCH_S", WATCH_S))
        except ValueError:
            raise DistributedError(f"JAXSTYLE_WATCH_S must be a number of seconds, got "
                                   f"{os.environ['JAXSTYLE_WATCH_S']!r}") from None
        if not 1 <= watch_s <= 3600:
            raise DistributedError(f"JAXSTYLE_WATCH_S must be 1 .. 3600 seconds, got {watch_s:g}")
    coordinator = coordinator or env["JAX_COORDINATOR_ADDRESS"]
    try:
        num_processes = num_processes if num_processes is not None else (
            None if env["JAX_NUM_PROCESSES"] is None else int(env["JAX_NUM_PROCESSES"]))
        process_id = process_id if process_id is not None else (
            None if env["JAX_PROCESS_ID"] is None else int(env["JAX_PROCESS_ID"]))
    except ValueError:
        raise DistributedError(f"JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers, got "
                               f"{env['JAX_NUM_PROCESSES']!r} and {env['JAX_PROCESS_ID']!r}") from None
    if num_processes is not None and num_processes < 1:
        raise DistributedError(f"the process count must be >= 1, got {num_processes}")
    if process_id is not None and num_processes is not None and not 0 <= process_id < num_processes:
        raise DistributedError(f"the process id must be in 0 .. {num_processes - 1}, got {process_id}")
    if coordinator is not None and ":" not in coordinator:
        raise DistributedError(f"the coordinator address must be host:port, got {coordinator!r}")
    try:
        jax.distributed.initialize(coordinator, num_processes, process_id, initialization_timeout=int(timeout_s),
                                   heartbeat_timeout_seconds=max(HEARTBEAT_S, int(2 * watch_s)))
    except (RuntimeError, ValueError) as e:
        first = _first_line(e)
        this = "?" if process_id is None else process_id
        raise DistributedError(f"jax.distributed could not start (coordinator {coordinator or 'from the cluster'}, "
                               f"{num_processes or '?'} processes, this one {this}): {first}") from None
    initialize.done = True
    if jax.process_count() > 1:
        threading.Thread(target=_watch, args=(float(watch_s),), daemon=True, name="jaxstyle-watch").start()


def _client():
    from jax._src import distributed  # the coordinator's key-value store has no public handle

    return distributed.global_state.client


def _stop(message: str) -> None:
    print(f"jaxstyle: error: process {jax.process_index()} of {jax.process_count()}: {message}", file=sys.stderr,
          flush=True)
    os._exit(1)


def _watch(watch_s: float, period_s: float = 1.0) -> None:
    """Beat, and watch the other processes' beats (see :func:`initialize`)."""
    client, me, n = _client(), jax.process_index(), jax.process_count()
    seen = {p: ("", time.monotonic()) for p in range(n) if p != me}
    beat = 0
    while True:
        beat += 1
        try:
            client.key_value_set(f"jaxstyle/beat/{me}", str(beat), allow_overwrite=True)
        except Exception as e:  # the store is process 0's: it is gone
            _stop(f"lost the coordinator (process 0) of this --distributed run ({_first_line(e)}); it exited or died")
        now = time.monotonic()
        for p in list(seen):
            if _try_get(client, f"jaxstyle/done/{p}") is not None:
                del seen[p]  # finished: its beat stops by design
                continue
            value = _try_get(client, f"jaxstyle/beat/{p}")
            if value is not None and value != seen[p][0]:
                seen[p] = (value, now)
            elif now - seen[p][1] > watch_s:
                _stop(f"process {p} stopped answering {watch_s:g} s ago (it exited with an error or died; see its "
                      "output); stopping too")
        time.sleep(period_s)


def _try_get(client, key: str) -> str | None:
    try:
        return client.key_value_try_get(key)
    except Exception:  # not set (yet)
        return None


def _first_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


def finish() -> None:
    """Say that this process finished its work, so the others do not take its silence for a death
    (call it once at a successful end of a ``--distributed`` command; nothing without one)."""
    if jax.process_count() > 1:
        _client().key_value_set(f"jaxstyle/done/{jax.process_index()}", "1", allow_overwrite=True)


def is_writer() -> bool:
    """Whether this process writes results: process 0 (the only one without ``jax.distributed``)."""
    return jax.process_index() == 0


def gather(tree: Any) -> Any:
    """Every array of ``tree`` whole on this process (numpy): an array spread over the devices of
    several processes is all-gathered (every process must call this); others are copied back."""
    from jax.experimental import multihost_utils

    def one(v):
        if isinstance(v, jax.Array) and not v.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(v, tiled=True))
        return np.asarray(v)

    return jax.tree.map(one, tree)


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
    target = replicated(mesh)
    if jax.process_count() > 1:  # host copies (the same on every process) go onto the global mesh
        tree = jax.tree.map(lambda v: v if isinstance(v, jax.Array) and v.sharding == target else np.asarray(v), tree)
    return jax.device_put(tree, target)


def shard_batches(batches_TxB, mesh: Mesh | None):
    """``(steps, batch)`` row indices with the batch axis split over the mesh's devices."""
    if mesh is None:
        return jax.numpy.asarray(batches_TxB)
    check_batch(mesh, np.shape(batches_TxB)[1])
    return jax.device_put(np.asarray(batches_TxB), NamedSharding(mesh, PartitionSpec(None, AXIS)))
