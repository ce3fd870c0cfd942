"""Every argument check, in one place, with one message per mistake.

The command line, the job pipeline, ``bench`` and the app all check scales, methods, variants,
steps, budgets, distances, seeds and devices here, before any work starts. Each check returns
the normalised value or raises a :class:`~geoscaler.errors.GeoscalerError` naming the flag.
:func:`check_scale` lives with the filters, which define what a scale is, and
:func:`check_variant` / :func:`check_preset` with the network method, which defines them; they
are used from here like the others.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from geoscaler.errors import GeoscalerError
from geoscaler.io import IMAGE_FORMATS
from geoscaler.methods import MethodOptions, get_method, is_learned, method_names
from geoscaler.methods.network import check_preset, check_variant
from geoscaler.protocol import VIEWS
from geoscaler.render.devices import resolve_device
from geoscaler.resize.filters import check_scale
from geoscaler.resize.sizes import SizePlan, SizeRule, parse_class_value, size_plan
from geoscaler.uv.uvmodes import uv_mode

DEFAULT_TIME_BUDGET = 60.0
"""Seconds a learned method's job may spend when ``--time-budget`` is not given (downsample,
the app), caching of the validation views included."""

MAX_SEED = 2**32 - 1


def check_scales(scales: Sequence[Any]) -> list[int]:
    """Distinct whole scale factors >= 2, in the given order."""
    if not scales:
        raise GeoscalerError("--scale: give at least one scale factor, e.g. --scale 4 8")
    return list(dict.fromkeys(check_scale(scale) for scale in scales))


def check_rules(scales: Sequence[Any]) -> list[SizeRule]:
    """Distinct size rules, in the given order: each whole scale factor >= 2 as the rule that
    divides by it, each :class:`~geoscaler.resize.sizes.SizeRule` as it is."""
    if not scales:
        raise GeoscalerError("--scale: give at least one scale factor, e.g. --scale 4 8")
    return list(
        dict.fromkeys(
            s if isinstance(s, SizeRule) else SizeRule(scale=check_scale(s)) for s in scales
        )
    )


DEFAULT_SCALE = 4
"""The reduction factor of every texture when neither ``--scale`` nor ``--max-size`` is given."""


def check_size_plan(
    scales: Sequence[str] | None, max_sizes: Sequence[str] | None, power_of_two: bool = False
) -> SizePlan:
    """The size rule of each texture class from the command line's ``--scale`` and
    ``--max-size`` values (each ``N`` for every class or ``CLASS=N``, repeatable; the last
    value for a class wins) and ``--power-of-two``. Neither given: ``--scale 4``."""
    scales, max_sizes = list(scales or []), list(max_sizes or [])
    if not scales and not max_sizes:
        scales = [str(DEFAULT_SCALE)]
    scale = dict(_class_value(text, "--scale") for text in scales)
    limit = dict(_class_value(text, "--max-size") for text in max_sizes)
    return size_plan(scale, limit, power_of_two)


def _class_value(text: str, flag: str) -> tuple[str, int]:
    try:
        return parse_class_value(text)
    except ValueError as error:
        raise GeoscalerError(f"{flag}: {error}") from None


def check_image_format(name: str | None) -> str | None:
    """``--image-format``: a format :data:`geoscaler.io.IMAGE_FORMATS` writes (``jpg``
    accepted), or None: each image in its input's format."""
    if name is None:
        return None
    name = {"jpg": "jpeg"}.get(name.strip().lower(), name.strip().lower())
    if name not in IMAGE_FORMATS:
        raise GeoscalerError(
            f"--image-format {name!r}: choose one of {', '.join(IMAGE_FORMATS)} (default: each "
            "image in the format it came in)"
        )
    return name


def check_method(name: str, flag: str = "--method") -> str:
    """The name of a registered method (or variant alias), given with ``flag``."""
    try:
        return get_method(name).name
    except GeoscalerError as error:
        raise GeoscalerError(f"{flag} {error}") from None


def check_methods(text: str | None, variants: str | None = None) -> list[str]:
    """Method names from ``"box,bicubic"`` (None: every registered method), checked.

    ``variants`` (``"base,full"``) replaces ``geoscaler`` in the list by one entry per network
    variant (``geoscaler-base, geoscaler-full``).
    """
    if text is None:
        names = method_names(aliases=False)
    else:
        names = [name.strip() for name in text.split(",") if name.strip()]
    if not names:
        raise GeoscalerError(f"--methods {text!r}: name at least one method")
    names = [check_method(name, "--methods") for name in names]
    if variants is not None:
        if "geoscaler" not in names:
            raise GeoscalerError("--variant: list geoscaler in --methods to run its variants")
        at = names.index("geoscaler")
        chosen = [check_variant(v.strip()) for v in variants.split(",") if v.strip()]
        names[at : at + 1] = [f"geoscaler-{v}" for v in chosen]
    if len(set(names)) != len(names):
        raise GeoscalerError(f"--methods {text!r}: a method is listed twice")
    return names


def check_steps(steps: int | None) -> int | None:
    """A step limit >= 1, or None (the method's default)."""
    if steps is not None and (isinstance(steps, bool) or steps < 1):
        raise GeoscalerError(f"--steps {steps}: must be at least 1")
    return steps


def check_time_budget(seconds: float | None) -> float | None:
    """A finite, positive number of seconds, or None (no flag given)."""
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise GeoscalerError(
            f"--time-budget {seconds}: must be a positive number of seconds (leave it out for "
            "the default)"
        )
    return seconds


def check_seed(seed: int) -> int:
    """A seed in 0 .. 2**32 - 1 (what numpy's and torch's generators take)."""
    if (
        isinstance(seed, bool)
        or not isinstance(seed, int | np.integer)
        or not 0 <= seed <= MAX_SEED
    ):
        raise GeoscalerError(f"--seed {seed}: must be a whole number from 0 to {MAX_SEED}")
    return int(seed)


def check_distance(distance: float) -> float:
    """A camera distance over 1 (outside the normalised mesh), finite."""
    if not (math.isfinite(distance) and distance > 1.0):
        raise GeoscalerError(
            f"--distance {distance}: must be over 1 (the mesh fits in the unit sphere); "
            "the protocol sets are 2.4, 1.5 (near) and 4.0 (far)"
        )
    return float(distance)


def check_distances(distances: Sequence[float]) -> list[float]:
    """Distinct camera distances, each over 1."""
    if not distances:
        raise GeoscalerError("--distance: give at least one camera distance, e.g. 2.4")
    return list(dict.fromkeys(check_distance(d) for d in distances))


PROTOCOLS = (1, 2)
"""The protocols of PROTOCOL.md: 1, the unlit base colour; 2, every map of a material lit."""


def check_protocol(protocol: int) -> int:
    """A protocol of PROTOCOL.md (:data:`PROTOCOLS`)."""
    if isinstance(protocol, bool) or protocol not in PROTOCOLS:
        raise GeoscalerError(
            f"--protocol {protocol!r}: must be 1 (unlit base colour, the paper's) or 2 (every "
            "map of a material lit)"
        )
    return int(protocol)


def check_view(view: int) -> int:
    """A protocol view index."""
    if not 0 <= view < VIEWS:
        raise GeoscalerError(f"--view {view}: must be 0 to {VIEWS - 1}")
    return view


def network_settings(preset: str | None = None, vgg19: str | Path | None = None) -> dict:
    """The network's settings from ``--preset`` and ``--vgg19`` (absent flags: none)."""
    settings: dict[str, Any] = {}
    if preset is not None:
        settings["preset"] = check_preset(preset)
    if vgg19 is not None:
        if not Path(vgg19).is_file():
            raise GeoscalerError(f"--vgg19 {vgg19}: no such file")
        settings["vgg19"] = str(vgg19)
    return settings


def method_settings(args: Any, methods: Sequence[str], uv_default: str = "keep") -> dict:
    """The settings of ``methods`` from parsed arguments: the network's ``--preset`` and
    ``--vgg19``, ``--renderer`` (what learned methods train through), ``direct``'s ``--uv``
    (keep, repack or auto; unset, ``uv_default`` for ``direct``: :func:`uv_mode`), a
    downsampling job's stop where nothing visible is left to gain (unless ``--full-budget``;
    ``compare`` and ``bench`` measure whole budgets), plus ``args.optimize``, loop overrides
    that a caller of :func:`geoscaler.cli.main` injected (None from the command line)."""
    settings = network_settings(args.preset, args.vgg19)
    renderer = getattr(args, "renderer", "exact")
    uv = uv_mode(getattr(args, "uv", None), uv_default, methods, renderer)
    if uv != "keep":
        settings["uv"] = uv
    loop = dict(args.optimize or {})
    if renderer != "exact":
        loop["training_renderer"] = renderer
    if not getattr(args, "full_budget", True):  # downsample and batch: on unless asked off
        loop["finish_when_invisible"] = True
    if loop:
        settings["optimize"] = loop
    return settings


def method_options(
    methods: Sequence[str],
    device: str = "auto",
    seed: int = 0,
    steps: int | None = None,
    time_budget: float | None = None,
    settings: Mapping[str, Any] | None = None,
    default_budget: float | None = None,
) -> MethodOptions:
    """Checked :class:`MethodOptions` for a job running ``methods``.

    ``default_budget`` applies when no budget is given and a learned method is among
    ``methods`` (``downsample`` and the app: :data:`DEFAULT_TIME_BUDGET`; ``compare`` and
    ``bench``: none).
    """
    resolve_device(device)  # no CUDA -> a clear error now, not after loading
    uv = (settings or {}).get("uv", "keep")
    if uv != "keep" and "direct" not in methods:
        raise GeoscalerError(f"--uv {uv}: only the direct method repacks UV charts")
    if uv != "keep" and (settings or {}).get("optimize", {}).get("training_renderer") == "soft":
        raise GeoscalerError(f"--uv {uv}: repacking trains through the exact renderer only")
    time_budget = check_time_budget(time_budget)
    if time_budget is None and any(is_learned(m) for m in methods):
        time_budget = default_budget
    return MethodOptions(
        device=device,
        seed=check_seed(seed),
        steps=check_steps(steps),
        time_budget=time_budget,
        settings=dict(settings or {}),
    )


def comparison_settings(args: Any) -> tuple[list[int], list[str], list[float], MethodOptions]:
    """The checked scales, methods, distances and method options of ``compare``/``bench``
    arguments (``--scale``, ``--methods``, ``--variant``, ``--distance``, ``--device``,
    ``--seed``, ``--steps``, ``--time-budget``): every argument error surfaces here, before
    any work."""
    scales = check_scales(args.scale)
    methods = check_methods(args.methods, args.variant)
    distances = check_distances(args.distance)
    settings = method_settings(args, methods)
    options = method_options(
        methods, args.device, args.seed, args.steps, args.time_budget, settings
    )
    return scales, methods, distances, options
