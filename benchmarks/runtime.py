"""Per-frame cost of the whole controller step (input assembly from the user's path and the last
output, the network, the root / phase / trajectory update), for the 2018 PFNN with a CP adapter
and the 2022 LPN with FiLM, at the papers' sizes. No motion capture needed.

    python benchmarks/runtime.py [--calls 200] [--runs 5] [--frames 120] [--batch 1024]

Rows, all measured in this run on the default JAX device:

* ``live step, batch 1``: one jitted call per displayed frame (``jaxstyle.control.model.step_fn``), the
  latency an interactive runtime sees, Python dispatch included; PFNN with the 50-bin table (the
  paper's runtime) and with the continuous phase; LPN-FiLM with its FiLM vector precomputed;
* ``scan, batch 1``: ``--frames`` frames generated in one jitted ``lax.scan`` (offline synthesis),
  per frame;
* ``scan, batch N``: ``N`` characters at once (``jaxstyle.control.model.rollout_batch``), frames per
  second over all.

Times are the mean and standard deviation over ``--runs`` runs (of ``--calls`` calls for the live
step). Weights are random at the papers' sizes (timing does not depend on their values); the
normalisation is the identity. The papers report 1.1 ms per frame (2018, CP adapter, Unity/C#
runtime) and 4.53 ms (2022, LPN-FiLM), each on its authors' CPU, for the network evaluation.
"""

from __future__ import annotations

import argparse
import os
import platform
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.control import controller, loop, lpn_controller, paths
from jaxstyle.control.controller import PFNNModel
from jaxstyle.control.lpn_controller import StyleNetModel
from jaxstyle.control.model import rollout, rollout_batch, step_fn
from jaxstyle.data.lpn_features import LPNLayout
from jaxstyle.data.normalise import Normaliser
from jaxstyle.data.pfnn_features import PFNNLayout
from jaxstyle.nn import pfnn, style_models
from jaxstyle.nn.style_models import StyleModelConfig
from jaxstyle.timing import time_call

PAPER_MS = {"PFNN-CP (2018)": 1.1, "LPN-FiLM (2022)": 4.53}
NUM_JOINTS = 31   # the PFNN's CMU-style skeleton: 186 inputs -> 342 outputs with the phase and root
NUM_BONES = 25    # the 2022 layout: 348 inputs, 342 outputs


def _identity(n: int) -> Normaliser:
    return Normaliser(np.zeros(n, np.float32), np.ones(n, np.float32))


def _stack(item, n):
    return jax.tree.map(lambda v: jnp.broadcast_to(v, (n,) + v.shape), item)


def _row(name, mode, batch, seconds_mean, seconds_std, frames):
    per = seconds_mean / frames
    print(f"| {name} | {mode} | {batch} | {per * 1e3:.3f} ± {seconds_std / frames * 1e3:.3f} | "
          f"{frames / seconds_mean:,.0f} | {PAPER_MS[name]} |", flush=True)


def pfnn_setup():
    layout = PFNNLayout(NUM_JOINTS)
    cfg = pfnn.PFNNConfig(input_size=layout.input_size, output_size=layout.output_size)
    key = jax.random.PRNGKey(0)
    params, adapter = pfnn.init_pfnn(key, cfg), pfnn.init_adapter(jax.random.PRNGKey(1), cfg)
    x = np.zeros(layout.input_size)
    x[layout.input_groups["trajectory_direction"]] = np.repeat([0.0, 1.0], 12)  # facing +Z throughout
    state = controller.initial_state(x, 0.0, NUM_JOINTS)
    return params, adapter, _identity(layout.input_size), _identity(layout.output_size), state


def lpn_setup():
    layout = LPNLayout(NUM_BONES)
    cfg = StyleModelConfig.paper("LPN FiLM")
    params = style_models.init_model(jax.random.PRNGKey(0), cfg)
    film_vector = style_models.example_style(params, cfg)
    x = np.zeros(layout.input_size)
    x[layout.input_groups["trajectory_direction"]] = np.repeat([0.0, 1.0], 12)
    state = lpn_controller.initial_state(x, np.zeros(8), NUM_BONES)
    return cfg, params, film_vector, _identity(layout.input_size), _identity(layout.output_size), state


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--frames", type=int, default=120, help="frames per scanned rollout")
    parser.add_argument("--batch", type=int, default=1024, help="characters in the batched rollout")
    args = parser.parse_args()
    dev = jax.devices()[0]
    print(f"device: {dev.device_kind} ({dev.platform}), {platform.machine()} host with {os.cpu_count()} cores, "
          f"jax {jax.__version__}\n")
    print("| model | mode | characters | ms per frame | frames/s | paper ms |\n|---|---|---|---|---|---|")
    controls = loop.signal_controls(paths.circle(args.frames / 60.0, 1.0, 2.0))
    one_control = (controls.offsets[0], controls.yaw[0])
    n = args.batch
    batch_controls = _stack(controls, n)
    scan_runs = dict(calls=1, runs=args.runs, warmup=1)

    name = "PFNN-CP (2018)"
    params, adapter, xn, yn, state = pfnn_setup()
    table, adapter_table = pfnn.discretise(params), pfnn.discretise(adapter)
    tabled = PFNNModel.create(table, (xn, yn), NUM_JOINTS, table=True)
    continuous = PFNNModel.create(params, (xn, yn), NUM_JOINTS)
    for label, step in (("live step, 50-bin table", step_fn(tabled, adapter_table)),
                        ("live step, continuous phase", step_fn(continuous, adapter))):
        mean, std = time_call(partial(step, state, one_control), calls=args.calls, runs=args.runs)
        _row(name, label, 1, mean, std, 1)
    run = partial(rollout, tabled, adapter_table, state, controls)
    _row(name, "scan, 50-bin table", 1, *time_call(run, **scan_runs), args.frames)
    run = partial(rollout_batch, continuous, _stack(adapter, n), _stack(state, n), batch_controls)
    out = run()
    _row(name, "scan, continuous phase", n, *time_call(run, **scan_runs), args.frames * n)
    finite = bool(np.isfinite(np.asarray(out.positions)).all())

    name = "LPN-FiLM (2022)"
    cfg, params, film_vector, xn, yn, state = lpn_setup()
    lpn = StyleNetModel.create(params, cfg, (xn, yn))
    step = step_fn(lpn, film_vector)
    mean, std = time_call(partial(step, state, one_control), calls=args.calls, runs=args.runs)
    _row(name, "live step, FiLM precomputed", 1, mean, std, 1)
    run = partial(rollout, lpn, film_vector, state, controls)
    _row(name, "scan", 1, *time_call(run, **scan_runs), args.frames)
    run = partial(rollout_batch, lpn, _stack(film_vector, n), _stack(state, n), batch_controls)
    out = run()
    _row(name, "scan", n, *time_call(run, **scan_runs), args.frames * n)
    finite &= bool(np.isfinite(np.asarray(out.positions)).all())
    print(f"\n(rollouts finite: {finite}; the papers' figures are the network call on their own CPUs, the rows "
          "here the whole controller step)")


if __name__ == "__main__":
    main()
