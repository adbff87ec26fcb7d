"""The seven style models of Table 2 (Mason, Starke & Komura 2022, section 5), one config away.

A model is an animation synthesis **backbone** with a style **modulation**:

* backbones (the expert blend ``alpha`` of :func:`jaxstyle.nn.lpn.synthesis_apply`):

  - ``"lpn"``: 8 experts gated by the local phases (8 values; gating 8 -> 32 -> 32 -> 8);
  - ``"mann"``: 8 experts gated by the end effectors' velocities (4 bones x 3 = 12 values, taken
    from the input frame, Zhang et al. 2018);
  - ``"pfnn"``: 4 control points blended by the Catmull-Rom weights of the global phase
    (:func:`jaxstyle.nn.pfnn.catmull_rom_weights`, Mason et al. 2018, Eq. 1a-1c; the PFNN is an
    expert blend whose gate is the spline).

* modulations (the per-style part):

  - ``"film"``: FiLM on both hidden layers, the parameters from the clip encoder
    (:mod:`jaxstyle.nn.film_generator`), LayerNorm before it (2022, Eq. 3). Per style at runtime: one
    2048-vector;
  - ``"onehot"``: a one-hot style vector concatenated to the input, i.e. a style-dependent shift
    of the first layer's features, with one shift per expert (blended like the weights; ``(S, K,
    H)``, per style ``K x 512``);
  - ``"resad"``: a residual adapter on the middle layer with its own dropout mask: on the PFNN the
    2018 CP adapter (rank 30, phase-dependent core; :func:`jaxstyle.nn.pfnn.cp_residual`, Mason et
    al. 2018, Eq. 6), on the LPN and MANN a full ``512 x 512`` matrix and bias
    (:func:`jaxstyle.nn.pfnn.full_residual`; the paper did not carry the CP's phase dependence over
    to the LPN).

``layer_norm`` defaults to on for FiLM models only (2022, Eq. 3's conditional normalisation; the
one-hot and adapter models are the original PFNN formulations without it).

Sizes for the paper's Table 2 come from :meth:`StyleModelConfig.paper`: the PFNN predicts one
phase update instead of 16 local-phase values (327 outputs), the MANN no phase at all (326).
:func:`parameter_counts` gives Table 2's three columns; they match the paper exactly except the
FiLM generator (see :mod:`jaxstyle.nn.film_generator`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.nn import film_generator as film
from jaxstyle.nn import lpn, pfnn

BACKBONES = ("lpn", "mann", "pfnn")
MODULATIONS = ("film", "onehot", "resad")
TABLE2 = {"PFNN One-hot": ("pfnn", "onehot"), "LPN One-hot": ("lpn", "onehot"), "PFNN Resad": ("pfnn", "resad"),
          "LPN Resad": ("lpn", "resad"), "PFNN FiLM": ("pfnn", "film"), "MANN FiLM": ("mann", "film"),
          "LPN FiLM": ("lpn", "film")}


@dataclasses.dataclass(frozen=True)
class StyleModelConfig:
    """A backbone x modulation model and its sizes (defaults: LPN FiLM on the 2022 layout)."""

    backbone: str = "lpn"
    modulation: str = "film"
    num_styles: int = 95
    input_size: int = 348
    hidden_size: int = 512
    output_size: int = 342
    gating_input: int = 8
    gating_hidden: int = 32
    num_experts: int = 8
    rank: int = 30
    layer_norm: bool | None = None
    generator: film.FiLMConfig = film.FiLMConfig()

    def __post_init__(self):
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.modulation not in MODULATIONS:
            raise ValueError(f"modulation must be one of {MODULATIONS}, got {self.modulation!r}")
        if self.modulation == "film" and self.generator.film_size != 4 * self.hidden_size:
            raise ValueError(f"the FiLM generator must output 4 x hidden_size = {4 * self.hidden_size} values, "
                             f"got film_size={self.generator.film_size}")
        if self.num_styles < 1:
            raise ValueError(f"num_styles must be positive, got {self.num_styles}")

    @property
    def experts(self) -> int:
        """Blended parameter sets: 4 control points for the PFNN, ``num_experts`` otherwise."""
        return pfnn.NUM_CONTROL_POINTS if self.backbone == "pfnn" else self.num_experts

    @property
    def normalise(self) -> bool:
        return self.modulation == "film" if self.layer_norm is None else self.layer_norm

    @classmethod
    def paper(cls, name: str, num_styles: int = 95) -> "StyleModelConfig":
        """One of :data:`TABLE2`'s models at the paper's sizes."""
        if name not in TABLE2:
            raise KeyError(f"unknown model {name!r}; Table 2 has {', '.join(TABLE2)}")
        backbone, modulation = TABLE2[name]
        output = {"lpn": 342, "mann": 326, "pfnn": 327}[backbone]
        gating = {"lpn": 8, "mann": 12, "pfnn": 1}[backbone]
        return cls(backbone, modulation, num_styles, output_size=output, gating_input=gating)


# --- parameters ---------------------------------------------------------------------------------

def _init_style(key, config: StyleModelConfig):
    c, s, h = config, config.num_styles, config.hidden_size
    if c.modulation == "film":
        return {"generator": film.init_generator(key, c.generator)}
    if c.modulation == "onehot":  # the one-hot rows of the first layer's (input + S) x H weights
        bound = math.sqrt(6.0 / (c.input_size + s + h))
        return {"onehot": jax.random.uniform(key, (s, c.experts, h), jnp.float32, -bound, bound)}
    keys = jax.random.split(key, s)
    if c.backbone == "pfnn":
        cp = pfnn.PFNNConfig(c.input_size, h, c.output_size, adapter="cp", rank=c.rank)
        return {"adapter": jax.vmap(lambda k: pfnn.init_adapter(k, cp))(keys)}
    return {"adapter": jax.vmap(lambda k: lpn._dense(k, h, h))(keys)}


def init_model(key: jax.Array, config: StyleModelConfig = StyleModelConfig()) -> dict:
    """``{"synthesis", "gating" (LPN, MANN), "style"}``: the per-style tables stacked on a leading
    style axis (one-hot, adapters) or the FiLM generator."""
    c = config
    ks, kg, kst = jax.random.split(key, 3)
    params = {"synthesis": lpn.init_synthesis(ks, c.experts, (c.input_size, c.hidden_size, c.hidden_size,
                                                              c.output_size)),
              "style": _init_style(kst, c)}
    if c.backbone != "pfnn":
        params["gating"] = lpn.init_gating(kg, (c.gating_input, c.gating_hidden, c.gating_hidden, c.num_experts))
    return params


def style_runtime(params: dict, config: StyleModelConfig, style: int | jax.Array):
    """Per-style runtime parameters of a one-hot or adapter model (its row of the style tables).
    FiLM models take a FiLM vector instead (:func:`jaxstyle.nn.film_generator.style_vectors`)."""
    if config.modulation == "film":
        raise ValueError("a FiLM model's style is a FiLM vector: "
                         "use jaxstyle.nn.film_generator.style_vectors or generator_apply")
    table = params["style"]["onehot" if config.modulation == "onehot" else "adapter"]
    return jax.tree.map(lambda v: v[style], table)


# --- forward ------------------------------------------------------------------------------------

def expert_blend(params: dict, config: StyleModelConfig, gate_BxG: jax.Array, *, key=None,
                 dropout_rate: jax.Array | float = 0.0) -> jax.Array:
    """``alpha (B, K)``: the gating network's softmax (LPN, MANN) or the spline weights of the
    global phase ``gate (B,)`` or ``(B, 1)`` in cycles (PFNN)."""
    if config.backbone == "pfnn":
        return pfnn.catmull_rom_weights(jnp.reshape(gate_BxG, (gate_BxG.shape[0],)))
    return lpn.gating_apply(params["gating"], gate_BxG, key=key, dropout_rate=dropout_rate)


def model_apply(params: dict, config: StyleModelConfig, x_BxI: jax.Array, gate_BxG: jax.Array, style, *,
                key: jax.Array | None = None, dropout_rate: jax.Array | float = 0.0) -> jax.Array:
    """``z (B, O)`` (Mason, Starke & Komura 2022, Eq. 4). ``style`` is the per-style runtime
    parameter: FiLM ``(B, 4H)`` or ``(4H,)``; a one-hot model's ``(K, H)`` shift table (a blend of
    tables interpolates styles); an adapter model's adapter (:func:`style_runtime`)."""
    kg, ks = jax.random.split(jax.random.PRNGKey(0) if key is None else key)
    alpha = expert_blend(params, config, gate_BxG, key=kg, dropout_rate=dropout_rate)
    kwargs = {}
    if config.modulation == "film":
        kwargs["film_params"] = style
    elif config.modulation == "onehot":
        kwargs["shift_BxH"] = alpha @ style
    elif config.backbone == "pfnn":
        kwargs["residual"] = lambda h: pfnn.apply_adapter(style, h, alpha)
    else:
        kwargs["residual"] = lambda h: pfnn.full_residual(h, style["W"], style["b"])
    return lpn.synthesis_apply(params["synthesis"], x_BxI, alpha, normalise=config.normalise, key=ks,
                               dropout_rate=dropout_rate, **kwargs)


def blend_styles(config: StyleModelConfig, styles_K, weights_K):
    """The runtime style of a blend of 2-3 styles with barycentric weights (section 4.4's triangle),
    from their runtime styles stacked on a leading axis: FiLM vectors ``(K, 4H)``
    (:func:`jaxstyle.nn.film_generator.interpolate`), one-hot rows or adapters. FiLM, the one-hot shift and the
    full LPN/MANN adapter are linear in their parameters, so the blend is the weighted sum; the
    PFNN's CP adapter blends exactly through :func:`jaxstyle.nn.pfnn.blend_adapters`."""
    if config.modulation == "film":
        return film.interpolate(styles_K, weights_K)
    if config.backbone == "pfnn" and config.modulation == "resad":
        return pfnn.blend_adapters(styles_K, weights_K)
    return pfnn.blend_trees(styles_K, weights_K, max_count=3)


def runtime_forward(params: dict, config: StyleModelConfig):
    """The runtime's network call: a jitted ``f(x_BxI, gate_BxG, style) -> z_BxO`` with dropout
    off and the style precomputed (a FiLM vector, a one-hot table row or one style's adapter);
    batch 1 is one character's frame."""
    return jax.jit(lambda x, g, s: model_apply(params, config, x, g, s))


def example_style(params: dict, config: StyleModelConfig, style: int = 0):
    """A style input for :func:`runtime_forward`: style ``style``'s runtime parameters, or for a
    FiLM model the FiLM vector of an all-zero clip (for timing and shape checks)."""
    if config.modulation == "film":
        g = config.generator
        return film.generator_apply(params["style"]["generator"], jnp.zeros((1, g.clip_frames, g.clip_features)))[0]
    return style_runtime(params, config, style)


# --- Table 2 parameter counts -------------------------------------------------------------------

def synthesis_size(config: StyleModelConfig) -> int:
    """A.S.N.: the expert layers and (LPN, MANN) the gating network."""
    c = config
    sizes = (c.input_size, c.hidden_size, c.hidden_size, c.output_size)
    layers = sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:], strict=True))
    gating = 0
    if c.backbone != "pfnn":
        g = (c.gating_input, c.gating_hidden, c.gating_hidden, c.num_experts)
        gating = sum(a * b + b for a, b in zip(g[:-1], g[1:], strict=True))
    return c.experts * layers + gating


def per_style_size(config: StyleModelConfig) -> int:
    """P.S.R.: per style at runtime: the FiLM vector, the one-hot rows of every expert, or the adapter."""
    c, h = config, config.hidden_size
    if c.modulation == "film":
        return c.generator.film_size
    if c.modulation == "onehot":
        return c.experts * h
    if c.backbone == "pfnn":
        return pfnn.adapter_size(pfnn.PFNNConfig(hidden_size=h, adapter="cp", rank=c.rank))
    return h * h + h


def style_network_size(config: StyleModelConfig) -> int:
    """S.M.N.: the FiLM generator, or every style's one-hot rows or adapter."""
    if config.modulation == "film":
        return film.generator_size(config.generator)
    return config.num_styles * per_style_size(config)


def parameter_counts(config: StyleModelConfig) -> dict[str, int]:
    """Table 2's columns: ``{"synthesis", "style_network", "per_style"}``."""
    return {"synthesis": synthesis_size(config), "style_network": style_network_size(config),
            "per_style": per_style_size(config)}


def tree_size(tree) -> int:
    """Number of values in a pytree of arrays (or shape structs)."""
    return int(sum(np.prod(v.shape) for v in jax.tree.leaves(tree)))
