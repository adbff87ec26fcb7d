"""Labels computed from motion: foot contacts, the global phase (Mason et al. 2018 / Holden et al. 2017), the
2022 paper's local motion phases and the sinusoid fit behind them."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["contacts", "phase", "local_phase", "sinusoid"])
