"""Downsampling methods. The registry (:mod:`~geoscaler.methods.registry`) imports none of
them; this package imports each method module, which registers itself, as trimesh's exchange
modules do: the filters first, then ``direct``, then the GeoScaler network and its variants."""

from geoscaler.methods import baselines, direct, network  # noqa: F401  (they register)
from geoscaler.methods.registry import (
    LayoutFacts,
    LoopFacts,
    Method,
    MethodOptions,
    MethodResult,
    NetworkFacts,
    RunContext,
    Shipping,
    TrialFacts,
    default_steps,
    get_method,
    is_learned,
    method_names,
    run_method,
)

__all__ = [
    "LayoutFacts",
    "LoopFacts",
    "Method",
    "MethodOptions",
    "MethodResult",
    "NetworkFacts",
    "RunContext",
    "Shipping",
    "TrialFacts",
    "default_steps",
    "get_method",
    "is_learned",
    "method_names",
    "run_method",
]
