"""The networks of both papers as pure functions: the PFNN with its residual adapters (Mason et al. 2018), the
local-phase network, FiLM and its generator, and the seven Table 2 style models (Mason et al. 2022); and
``modules``, Flax NNX modules that are a façade over the PFNN and the FiLM style models."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["pfnn", "lpn", "film_generator", "style_models", "modules"])
