"""Result rows: what the job measured of one output on one view set (the keys of reports,
JSON and benchmark tables)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from geoscaler.methods import MethodResult
from geoscaler.optim.validation import Validation
from geoscaler.protocol import BYTES_PER_TEXEL, VALIDATION_DISTANCE
from geoscaler.render.metrics import METRIC_NAMES, mean_metrics
from geoscaler.render.views import ViewCache

ROW_KEYS = (
    "method",
    "scale",
    "distance",
    "views",
    "texture_size",
    "texture_bytes",
    *METRIC_NAMES,
    "gain_db",
    "seconds",
    "shipped",
)
"""Keys of a result row: ``texture_size`` is ``[width, height]`` of the largest texture,
``texture_bytes`` the RGBA8 memory of all textures (``BYTES_PER_TEXEL``), PSNRs and gain in
dB (``+inf`` for a render identical to the reference), ``seconds`` the method's wall time,
``shipped`` the method whose textures the row scores: the row's own, or for a learned method
the filter the validation ranked above it (:func:`geoscaler.pipeline.job.no_worse_than_filters`)."""


def texture_facts(textures: Sequence[np.ndarray | None]) -> tuple[list[int], int]:
    """``([width, height]`` of the largest texture, RGBA8 bytes of them all)``."""
    present = [t for t in textures if t is not None]
    if not present:
        return [0, 0], 0
    largest = max(present, key=lambda t: t.shape[0] * t.shape[1])
    texels = sum(t.shape[0] * t.shape[1] for t in present)
    return [int(largest.shape[1]), int(largest.shape[0])], int(texels * BYTES_PER_TEXEL)


def protocol_row(
    result: MethodResult, name: str, scale: int, distance: float, cache: ViewCache
) -> dict[str, Any]:
    """A row without its gain: the output scored on all views of a cached view set."""
    metrics = mean_metrics(cache.score(result.textures, result.uvs))
    return scored_row(result, name, scale, distance, metrics, len(cache))


def scored_row(
    result: MethodResult,
    name: str,
    scale: int,
    distance: float,
    metrics: dict[str, float],
    views: int,
) -> dict[str, Any]:
    """A row without its gain, of mean ``metrics`` measured on ``views`` views."""
    size, nbytes = texture_facts(result.textures)
    return {
        "method": name,
        "scale": scale,
        "distance": distance,
        "views": views,
        "texture_size": size,
        "texture_bytes": nbytes,
        **{key: metrics[key] for key in METRIC_NAMES},
        "seconds": result.seconds,
        "shipped": result.shipped(name),
    }


def validation_row(
    result: MethodResult, name: str, scale: int, validation: Validation
) -> dict[str, Any]:
    """A row without its gain: the output on the validation's Q views."""
    metrics = validation.score(result.textures, result.uvs, ["Q"])["Q"]
    size, nbytes = texture_facts(result.textures)
    return {
        "method": name,
        "scale": scale,
        "distance": VALIDATION_DISTANCE,
        "views": validation.counts["Q"] if validation.counts else 0,
        "texture_size": size,
        "texture_bytes": nbytes,
        **{key: metrics[key] for key in METRIC_NAMES},
        "seconds": result.seconds,
        "shipped": result.shipped(name),
    }
