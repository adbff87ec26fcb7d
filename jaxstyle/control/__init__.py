"""Driving a character: paths and the controllers of both papers' networks."""

from jaxstyle._lazy import lazy_module

__getattr__, __dir__ = lazy_module(__name__, ["paths", "controller", "lpn_controller"])
