"""Data-parallel LPN-FiLM training on 4 host devices: a sharded step equals the
one-device step, a sharded run checkpoints and resumes on one device with the one-device result,
and the batch must divide over the devices. Runs in a subprocess with
``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (the device count is fixed when JAX starts)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent("""
    import sys
    import jax, jax.numpy as jnp, numpy as np
    from jaxstyle.mason2022 import styledata
    from jaxstyle.mason2022 import train as T
    from jaxstyle.train import shard
    from tests.test_lpn import small_config, synthetic_data

    assert jax.device_count() == 4, jax.devices()
    data = synthetic_data()
    config = T.LPNTrainConfig(model=small_config(), batch_size=8, learning_rate=1e-3, epochs=2, log_every=100)

    def diff(a, b):
        return max(float(jnp.max(jnp.abs(x - y))) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))

    # one step, sharded against unsharded
    mesh = shard.data_mesh("all")
    batches, styles, clips = T.epoch_batches(data, config, 0)
    keys = jax.random.split(jax.random.PRNGKey(3), 1)
    def step(mesh):
        state = T.init_state(jax.random.PRNGKey(0), config)
        p, o = shard.replicate((state.params, state.opt_state), mesh)
        arrays = shard.replicate(styledata.device_arrays(data), mesh)
        b = shard.shard_batches(batches[:1], mesh)
        s, c, k = shard.replicate((jnp.asarray(styles[:1]), jnp.asarray(clips[:1]), keys), mesh)
        return T._train_chunk(p, o, arrays, b, s, c, k, jnp.float32(0.3), jnp.float32(1.0), config=config.model,
                              bones=styledata.StaticBones(data.bones), learning_rate=config.learning_rate)
    one, sharded = step(None), step(mesh)
    assert len(shard.shard_batches(batches[:1], mesh).sharding.device_set) == 4
    assert len(sharded[0]["synthesis"]["l0"]["W"].sharding.device_set) == 4
    assert sharded[0]["synthesis"]["l0"]["W"].sharding.is_fully_replicated
    print("step", diff(one[0], sharded[0]), diff(one[2], sharded[2]), diff(one[0], T.init_state(
        jax.random.PRNGKey(0), config).params))

    if len(sys.argv) > 2:  # two epochs: sharded for one (checkpointed), resumed on one device,
        directory = sys.argv[1]  # against one device throughout
        T.train(data, config, directory, progress=False, devices="all", stop_after_epochs=1)
        resumed = T.train(data, config, directory, progress=False, devices=None)
        plain = T.train(data, config, progress=False)
        print("epochs", diff(resumed.params, plain.params), int(resumed.epoch))
    try:
        T.train(data, T.LPNTrainConfig(model=small_config(), batch_size=6), progress=False, devices="all")
    except ValueError as e:
        print("refused", e)
""")


def _run(tmp_path, *extra):
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4",
           "JAX_PLATFORMS": "cpu",
           "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(tmp_path / "run"), *extra], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-4000:]
    return {line.split()[0]: line.split()[1:] for line in out.stdout.splitlines() if line.strip()}


def _check_step(lines):
    step_params, step_losses, moved = (float(v) for v in lines["step"])
    # the sharded step sums the batch's gradient per device, then across devices: float32 sums in
    # another order, ~1e-7 relative; one Adam step moves each weight by ~lr = 1e-3
    assert moved > 1e-4
    assert step_params <= 1e-6 and step_losses <= 1e-5
    assert "does not divide over 4 devices" in " ".join(lines["refused"])


def test_a_sharded_step_equals_the_one_device_step(tmp_path):
    _check_step(_run(tmp_path))


@pytest.mark.slow
def test_a_sharded_run_checkpoints_and_resumes_on_one_device(tmp_path):
    lines = _run(tmp_path, "resume")
    _check_step(lines)
    epochs_diff, epoch = float(lines["epochs"][0]), int(lines["epochs"][1])
    assert epoch == 2
    assert epochs_diff <= 1e-4  # 48 Adam steps of rounding differences in the sum order
