"""Flax NNX modules over the pure networks: a façade, so Flax code can hold and train them.

jaxstyle's networks are pure functions over parameter pytrees (:mod:`jaxstyle.nn.pfnn`,
:mod:`jaxstyle.nn.style_models`); they stay the single source of truth. The modules here hold
those same pytrees with every array in an :class:`flax.nnx.Param`, and their ``__call__`` rebuilds
the pytree and calls the pure function: no maths is written twice, so a module and its pure
function give the same outputs and the same gradients (``tests/test_modules.py`` checks both).

* :class:`PFNNModule` (also ``jaxstyle.PFNNModule``): the 2018 PFNN
  (:func:`jaxstyle.nn.pfnn.pfnn_apply`) with an optional table of per-style residual adapters
  (stacked on a leading style axis, as :func:`jaxstyle.mason2018.train.init_state` keeps them).
* :class:`LPNFiLMModule` (also ``jaxstyle.LPNFiLMModule``): a 2022 FiLM style model (default
  LPN FiLM, :func:`jaxstyle.nn.style_models.model_apply`) with its FiLM generator
  (:func:`jaxstyle.nn.film_generator.generator_apply`), driven by a style clip or a precomputed
  FiLM vector.

Weights cross the boundary both ways: ``Module(config, rngs=nnx.Rngs(0))`` initialises with the
pure ``init_*`` functions (``rngs.params()`` is the key), ``module.params()`` returns the pure
pytree (exactly the arrays held), and ``Module.from_params(config, params)`` wraps a pure pytree
(e.g. restored from a jaxstyle checkpoint) without copying or re-initialising.

Dropout needs randomness: pass ``key=`` (a JAX key, used exactly as the pure function uses it) or
``rngs=`` (an :class:`flax.nnx.Rngs`; its ``dropout`` stream gives the key). A non-zero rate
without either is an error, rather than the pure functions' fixed default key.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from jaxstyle.nn import film_generator as film
from jaxstyle.nn import pfnn, style_models

__all__ = ["LPNFiLMModule", "PFNNModule"]

_IS_VARIABLE = lambda v: isinstance(v, nnx.Variable)  # noqa: E731
_NO_TREE = object()  # the sentinel of __init__'s private ``_tree``: initialise from rngs


def _wrap(tree):
    """The pure pytree with each array in an :class:`nnx.Param` (``None`` stays ``None``)."""
    if tree is None:
        return None
    return nnx.data(jax.tree.map(lambda v: nnx.Param(jnp.asarray(v)), tree))


def _unwrap(tree):
    """The pure pytree of the arrays held in ``tree``'s :class:`nnx.Param` leaves."""
    if tree is None:
        return None
    return jax.tree.map(lambda v: v[...], tree, is_leaf=_IS_VARIABLE)


def _check_like(what: str, tree, reference) -> None:
    """``tree`` must have ``reference``'s structure and shapes (dtypes may differ, e.g. a base cast
    to bfloat16 by :func:`jaxstyle.nn.pfnn.cast_weights`)."""
    if jax.tree.structure(tree) != jax.tree.structure(reference):
        raise ValueError(f"{what} do not match the config: expected the structure {jax.tree.structure(reference)}, "
                         f"got {jax.tree.structure(tree)}")
    bad = [f"{jax.tree_util.keystr(path)}: {tuple(jnp.shape(v))} != {r.shape}"
           for (path, v), r in zip(jax.tree_util.tree_leaves_with_path(tree), jax.tree.leaves(reference), strict=True)
           if tuple(jnp.shape(v)) != tuple(r.shape)]
    if bad:
        raise ValueError(f"{what} do not match the config: " + "; ".join(bad))


def _dropout_key(key, rngs, dropout_rate, what: str):
    """The key for the pure function: ``key``, else ``rngs.dropout()``, else ``None`` (rate 0)."""
    if key is not None and rngs is not None:
        raise ValueError(f"{what}: give key= or rngs=, not both")
    if key is None and rngs is not None:
        return rngs.dropout()
    if key is None and not isinstance(dropout_rate, jax.Array) and np.any(np.asarray(dropout_rate) != 0):
        raise ValueError(f"{what}: dropout_rate={dropout_rate} needs key= or rngs= for the dropout masks")
    return key


def _init_pfnn(key: jax.Array, config: pfnn.PFNNConfig, num_styles: int) -> tuple[dict, dict | None]:
    """The base and the stacked adapters as :func:`jaxstyle.mason2018.train.init_state` makes them."""
    kp, ka = jax.random.split(key)
    adapters = None
    if num_styles:
        adapters = jax.vmap(lambda k: pfnn.init_adapter(k, config))(jax.random.split(ka, num_styles))
    return pfnn.init_pfnn(kp, config), adapters


class PFNNModule(nnx.Module):
    """The 2018 phase-functioned network with an optional table of per-style residual adapters.

    A façade over :func:`jaxstyle.nn.pfnn.pfnn_apply` (the source of truth): the base
    (:func:`jaxstyle.nn.pfnn.init_pfnn`'s pytree) and the adapters
    (:func:`jaxstyle.nn.pfnn.init_adapter`'s pytree stacked over ``num_styles``) live in
    :class:`flax.nnx.Param` leaves so that :func:`flax.nnx.grad`, :class:`flax.nnx.Optimizer` and
    other Flax modules can use them; calling the module calls the pure function on them.

    ``PFNNModule(config, num_styles=S, rngs=nnx.Rngs(0))`` initialises as
    :func:`jaxstyle.mason2018.train.init_state` does from the key ``rngs.params()`` (split into the
    base's and the adapters' keys); ``num_styles=0`` holds no adapters. ``config=None`` is the
    paper's :class:`jaxstyle.nn.pfnn.PFNNConfig`.
    """

    def __init__(self, config: pfnn.PFNNConfig | None = None, *, num_styles: int = 0,
                 rngs: nnx.Rngs | None = None, _tree=_NO_TREE):
        config = pfnn.PFNNConfig() if config is None else config
        if _tree is _NO_TREE:
            if rngs is None:
                raise ValueError("PFNNModule needs rngs=nnx.Rngs(seed) to initialise (or use PFNNModule.from_params)")
            if num_styles < 0:
                raise ValueError(f"num_styles must be 0 or more, got {num_styles}")
            params, adapters = _init_pfnn(rngs.params(), config, num_styles)
        else:
            params, adapters = _tree
        self.config = config
        self.num_styles = 0 if adapters is None else int(jax.tree.leaves(adapters)[0].shape[0])
        self.base = _wrap(params)
        self.adapter_table = _wrap(adapters)

    @classmethod
    def from_params(cls, config: pfnn.PFNNConfig, params: dict, adapters: dict | None = None) -> "PFNNModule":
        """The module holding the pure base ``params`` (:func:`jaxstyle.nn.pfnn.init_pfnn`'s
        structure) and optionally ``adapters`` stacked on a leading style axis (as in
        :func:`jaxstyle.mason2018.train.init_state`; stack one adapter ``a`` with
        ``jax.tree.map(lambda v: v[None], a)``). Shapes are checked against ``config``."""
        key = jax.random.PRNGKey(0)
        _check_like("PFNN params", params, jax.eval_shape(lambda: pfnn.init_pfnn(key, config)))
        if adapters is not None:
            leaves = jax.tree.leaves(adapters)
            count = jnp.shape(leaves[0])[0] if leaves and jnp.ndim(leaves[0]) else 0
            expected = jax.eval_shape(lambda: jax.vmap(lambda k: pfnn.init_adapter(k, config))(
                jax.random.split(key, max(count, 1))))
            _check_like("PFNN adapters (stacked, leading axis = style)", adapters, expected)
        return cls(config, _tree=(params, adapters))

    def params(self) -> dict:
        """The base's pure pytree, as :func:`jaxstyle.nn.pfnn.pfnn_apply` takes it."""
        return _unwrap(self.base)

    def adapters(self) -> dict | None:
        """The adapters' pure pytree stacked on a leading style axis, or ``None`` without adapters."""
        return _unwrap(self.adapter_table)

    def adapter(self, style: int | jax.Array) -> dict:
        """Style ``style``'s adapter (a pure pytree for ``adapter=`` of the pure functions)."""
        if self.adapter_table is None:
            raise ValueError("this PFNN holds no adapters (num_styles=0)")
        return jax.tree.map(lambda v: v[style], self.adapters())

    def __call__(self, x_BxI: jax.Array, phase_B: jax.Array, *, style: int | jax.Array | None = None,
                 adapter: dict | None = None, dropout_rate: jax.Array | float = 0.0,
                 adapter_dropout_rate: jax.Array | float | None = None, key: jax.Array | None = None,
                 rngs: nnx.Rngs | None = None) -> jax.Array:
        """``y (B, O)``: :func:`jaxstyle.nn.pfnn.pfnn_apply` with the held base and the adapter of
        ``style`` (an index into the held table), or an external pure ``adapter`` (e.g. a few-shot
        or blended one), or neither (the average motion). ``key``/``rngs`` give the dropout masks."""
        if style is not None and adapter is not None:
            raise ValueError("give style= (a held adapter) or adapter= (a pure adapter), not both")
        if style is not None:
            adapter = self.adapter(style)
        key = _dropout_key(key, rngs, dropout_rate, "PFNN")
        return pfnn.pfnn_apply(self.params(), x_BxI, phase_B, adapter=adapter, key=key, dropout_rate=dropout_rate,
                               adapter_dropout_rate=adapter_dropout_rate)


class LPNFiLMModule(nnx.Module):
    """A 2022 style model with FiLM modulation (default: LPN FiLM) and its FiLM generator.

    A façade over :func:`jaxstyle.nn.style_models.model_apply` and
    :func:`jaxstyle.nn.film_generator.generator_apply` (the source of truth): the pytree of
    :func:`jaxstyle.nn.style_models.init_model` (``{"synthesis", "gating", "style": {"generator"}}``)
    lives in :class:`flax.nnx.Param` leaves; calling the module calls the pure functions on it.

    ``config`` is a :class:`jaxstyle.nn.style_models.StyleModelConfig` with ``modulation="film"``
    (the ``"pfnn"`` and ``"mann"`` backbones work too: Table 2's PFNN FiLM and MANN FiLM).
    ``LPNFiLMModule(config, rngs=nnx.Rngs(0))`` initialises as :func:`jaxstyle.mason2022.train.init_state`
    does, from the key ``rngs.params()``. ``config=None`` is the paper's LPN FiLM.
    """

    def __init__(self, config: style_models.StyleModelConfig | None = None, *,
                 rngs: nnx.Rngs | None = None, _tree=_NO_TREE):
        config = style_models.StyleModelConfig() if config is None else config
        if config.modulation != "film":
            raise ValueError("LPNFiLMModule is a FiLM model: config.modulation must be 'film', got "
                             f"{config.modulation!r}")
        if _tree is _NO_TREE:
            if rngs is None:
                raise ValueError("LPNFiLMModule needs rngs=nnx.Rngs(seed) to initialise "
                                 "(or use LPNFiLMModule.from_params)")
            _tree = style_models.init_model(rngs.params(), config)
        self.config = config
        self.weights = _wrap(_tree)

    @classmethod
    def from_params(cls, config: style_models.StyleModelConfig, params: dict) -> "LPNFiLMModule":
        """The module holding the pure ``params`` of :func:`jaxstyle.nn.style_models.init_model`
        (e.g. ``state.params`` of :func:`jaxstyle.mason2022.train.init_state`); shapes are
        checked against ``config``."""
        if config.modulation != "film":
            raise ValueError("LPNFiLMModule is a FiLM model: config.modulation must be 'film', got "
                             f"{config.modulation!r}")
        key = jax.random.PRNGKey(0)
        _check_like("LPNFiLM params", params, jax.eval_shape(lambda: style_models.init_model(key, config)))
        return cls(config, _tree=params)

    def params(self) -> dict:
        """The pure pytree, as :func:`jaxstyle.nn.style_models.model_apply` takes it."""
        return _unwrap(self.weights)

    def film(self, clip_BxTxC: jax.Array, *, dropout_rate: jax.Array | float = 0.0, key: jax.Array | None = None,
             rngs: nnx.Rngs | None = None) -> jax.Array:
        """FiLM parameters ``(B, 4H)`` of normalised style clips ``(B, frames, features)``
        (:func:`jaxstyle.nn.film_generator.generator_apply`; a style's runtime vector is the mean
        over its clips, :func:`jaxstyle.nn.film_generator.style_vectors`)."""
        key = _dropout_key(key, rngs, dropout_rate, "LPNFiLM.film")
        return film.generator_apply(self.params()["style"]["generator"], clip_BxTxC, key=key,
                                    dropout_rate=dropout_rate)

    def __call__(self, x_BxI: jax.Array, gate_BxG: jax.Array, *, clip: jax.Array | None = None,
                 film_params: jax.Array | None = None, dropout_rate: jax.Array | float = 0.0,
                 key: jax.Array | None = None, rngs: nnx.Rngs | None = None) -> jax.Array:
        """``z (B, O)``: :func:`jaxstyle.nn.style_models.model_apply` styled by a style ``clip``
        ``(1 or B, frames, features)`` run through the generator (as in training), or by a
        precomputed ``film_params`` vector ``(4H,)`` or ``(B, 4H)`` (as at runtime).

        ``gate_BxG`` is the gating input: local phases (LPN), end-effector velocities (MANN) or the
        global phase (PFNN). With a clip, ``key`` is split into the generator's and the model's
        keys as :func:`jaxstyle.mason2022.loss.batch_loss` splits it."""
        if (clip is None) == (film_params is None):
            raise ValueError("give exactly one of clip= (a style clip) and film_params= (a FiLM vector)")
        key = _dropout_key(key, rngs, dropout_rate, "LPNFiLM")
        params = self.params()
        if clip is not None:
            k_style, key = jax.random.split(jax.random.PRNGKey(0) if key is None else key)
            film_params = film.generator_apply(params["style"]["generator"], clip, key=k_style,
                                               dropout_rate=dropout_rate)
        return style_models.model_apply(params, self.config, x_BxI, gate_BxG, film_params, key=key,
                                        dropout_rate=dropout_rate)


