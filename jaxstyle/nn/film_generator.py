"""The style modulation network: a FiLM generator on style clips (Mason, Starke & Komura 2022, 4.2).

``Psi(y) = {gamma1, beta1, gamma2, beta2}`` (Mason, Starke & Komura 2022, Eq. 2) from a clip
``y (240, 300)`` of joint features: two 1-D convolutions over time (256 filters of width 25, ReLU,
'same' padding), each followed by max-pooling by 2, then dense 2048 (ReLU, dropout) and dense
2048 = the four 512-vectors.

At runtime the generator is not run: a style is one precomputed 2048-vector
(:func:`style_vectors`, the mean over a style's clips, section 4.4), and styles are interpolated
by blending these vectors with barycentric weights (:func:`interpolate`).

Parameter count: :func:`generator_size` gives 39,214,592 for the paper's sizes; the paper's
Table 2 lists 35,668,530 for the style modulation network. A search over 'same'/'valid'
padding, pooling by 1 or 2, filter widths 3-50, 64-512 filters, clip widths 75-348, dense widths
512-4096 and with or without biases found no combination giving that number, so
jaxstyle builds the network as the text describes it (section 4.3 and the authors' code layout in
``IMPLEMENTATION_FACTS.md``) and reports both counts (``experiments/mason2022_table2.py``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxstyle.nn import pfnn
from jaxstyle.nn.lpn import glorot


@dataclasses.dataclass(frozen=True)
class FiLMConfig:
    """Sizes of the FiLM generator (paper: 240 x 300 clips, 256 filters of width 25, 2048 units,
    FiLM for two hidden layers of 512: 2048 outputs)."""

    clip_frames: int = 240
    clip_features: int = 300
    filters: int = 256
    width: int = 25
    hidden: int = 2048
    film_size: int = 2048  # 4 x the synthesis network's hidden size

    @property
    def pooled_frames(self) -> int:
        return self.clip_frames // 4


def generator_size(config: FiLMConfig = FiLMConfig()) -> int:
    """Parameters of the generator: two convolutions, two dense layers, with biases."""
    c = config
    conv = c.width * c.clip_features * c.filters + c.filters + c.width * c.filters * c.filters + c.filters
    return conv + c.pooled_frames * c.filters * c.hidden + c.hidden + c.hidden * c.film_size + c.film_size


def init_generator(key: jax.Array, config: FiLMConfig = FiLMConfig()) -> dict:
    """Glorot-uniform weights, zero biases. Convolution kernels are ``(width, in, out)``."""
    c = config
    k1, k2, k3, k4 = jax.random.split(key, 4)
    zeros = lambda n: jnp.zeros((n,), jnp.float32)  # noqa: E731
    return {"conv1": {"W": glorot(k1, (c.width, c.clip_features, c.filters), jnp.float32), "b": zeros(c.filters)},
            "conv2": {"W": glorot(k2, (c.width, c.filters, c.filters), jnp.float32), "b": zeros(c.filters)},
            "dense1": {"W": glorot(k3, (c.pooled_frames * c.filters, c.hidden), jnp.float32), "b": zeros(c.hidden)},
            "dense2": {"W": glorot(k4, (c.hidden, c.film_size), jnp.float32), "b": zeros(c.film_size)}}


IM2COL_VALUES = 1 << 24
"""Up to this many patch values (batch x frames x width x channels) :func:`_conv` is one matrix
product of the clip's patches (im2col); above it (a batch of clips at test time) XLA's convolution."""


def _conv(layer: dict, x_BxTxC: jax.Array) -> jax.Array:
    """'Same' 1-D convolution (the kernel centred, ``(width - 1) // 2`` frames of zeros before);
    products in the kernel's dtype (bfloat16 for mixed-precision training,
    :func:`jaxstyle.mason2022.train.train`), accumulated and returned in float32.

    A training step convolves ONE clip: there the convolution is the product of the clip's
    ``(T, width x C)`` patches with the ``(width x C, F)`` kernel, whose gradients are two plain
    products. XLA's convolution gives the same values, but on CPU the gradients of the two
    convolutions of one clip took ~85% of an LPN-FiLM step with it (1.75 of 2.0 s;
    ``benchmarks/lpn_training.py``, ``docs/mason2022.md``, "Training speed")."""
    w = layer["W"]
    width, channels, filters = w.shape
    b, t, _ = x_BxTxC.shape
    x = x_BxTxC.astype(w.dtype)
    if b * t * width * channels > IM2COL_VALUES:
        out = jax.lax.conv_general_dilated(x, w, window_strides=(1,), padding="SAME",
                                           dimension_numbers=("NWC", "WIO", "NWC"), preferred_element_type=jnp.float32)
        return out + layer["b"]
    lo = (width - 1) // 2
    xp = jnp.pad(x, ((0, 0), (lo, width - 1 - lo), (0, 0)))
    patches_BxTxWC = jnp.concatenate([xp[:, i:i + t] for i in range(width)], axis=-1)
    out = jnp.matmul(patches_BxTxWC, w.reshape(width * channels, filters), preferred_element_type=jnp.float32)
    return out + layer["b"]


def _dense(layer: dict, h_BxI: jax.Array) -> jax.Array:
    """``h W + b``, the product in ``W``'s dtype accumulated in float32 (as :func:`_conv`)."""
    w = layer["W"]
    return jnp.matmul(h_BxI.astype(w.dtype), w, preferred_element_type=jnp.float32) + layer["b"]


def _max_pool2(x_BxTxC: jax.Array) -> jax.Array:
    b, t, c = x_BxTxC.shape
    return jnp.max(x_BxTxC[:, :t // 2 * 2].reshape(b, t // 2, 2, c), axis=2)


def generator_apply(params: dict, clip_BxTxC: jax.Array, *, key: jax.Array | None = None,
                    dropout_rate: jax.Array | float = 0.0) -> jax.Array:
    """FiLM parameters ``(B, 2048)`` of ``B`` normalised clips ``(B, 240, 300)``: ``Psi(y)`` of
    Mason, Starke & Komura 2022, Eq. 2 (split with :func:`jaxstyle.nn.lpn.split_film`)."""
    clip_BxTxC = jnp.asarray(clip_BxTxC)
    if clip_BxTxC.ndim != 3 or clip_BxTxC.shape[2] != params["conv1"]["W"].shape[1]:
        raise ValueError(f"clips must be (B, frames, {params['conv1']['W'].shape[1]}), got {clip_BxTxC.shape}")
    frames = params["dense1"]["W"].shape[0] // params["conv2"]["W"].shape[2] * 4
    if clip_BxTxC.shape[1] != frames:
        raise ValueError(f"clips must have {frames} frames, got {clip_BxTxC.shape[1]}")
    h = _max_pool2(jax.nn.relu(_conv(params["conv1"], clip_BxTxC)))
    h = _max_pool2(jax.nn.relu(_conv(params["conv2"], h)))
    h = jax.nn.relu(_dense(params["dense1"], h.reshape(h.shape[0], -1)))
    h = pfnn.dropout(jax.random.PRNGKey(0) if key is None else key, h, dropout_rate)
    return _dense(params["dense2"], h)


_generate = jax.jit(generator_apply)


def clip_films(params: dict, clips_CxTxF: np.ndarray, chunk: int = 64) -> np.ndarray:
    """``(C, 2048)`` FiLM parameters of every clip, dropout off, ``chunk`` clips per call."""
    clips_CxTxF = np.asarray(clips_CxTxF, np.float32)
    if len(clips_CxTxF) == 0:
        raise ValueError("no clips")
    return np.concatenate([np.asarray(_generate(params, clips_CxTxF[a:a + chunk]))
                           for a in range(0, len(clips_CxTxF), chunk)])


def style_vectors(params: dict, clips_CxTxF: np.ndarray, clip_style_C: np.ndarray, num_styles: int) -> np.ndarray:
    """``(S, 2048)`` one precomputed FiLM vector per style: the mean over its clips (section 4.4).
    A style without clips is an error naming it."""
    clip_style_C = np.asarray(clip_style_C)
    missing = [s for s in range(num_styles) if not (clip_style_C == s).any()]
    if missing:
        raise ValueError(f"styles {missing} have no clip to compute a FiLM vector from")
    films = clip_films(params, clips_CxTxF)
    return np.stack([films[clip_style_C == s].mean(axis=0) for s in range(num_styles)])


def interpolate(vectors_Kx4H: jax.Array, weights_K) -> jax.Array:
    """The FiLM vector of a blend of 2 or 3 styles: ``sum_k w_k v_k`` with barycentric weights
    (non-negative, summing to 1; section 4.4's triangle of three styles)."""
    return pfnn.blend_trees(jnp.asarray(vectors_Kx4H), weights_K, max_count=3, what="style vector")
