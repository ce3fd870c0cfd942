"""The sizes users ask for: a reduction factor, a longest side, powers of two, per texture class.

A :class:`SizeRule` turns an input texture's ``(height, width)`` into the size it ships at, in
this order: divide each side by ``scale`` (rounded half up), shrink so that the longer side is
at most ``max_size`` (aspect kept, rounded half up), round each side to the nearest power of
two when ``power_of_two`` (ties up, never above ``max_size``). A rule never enlarges a side: the
result is at most the input. :class:`SizePlan` holds one rule per texture class (colour,
normal, data), as gltfpack's ``-ts``/``-tl``/``-tp`` do.

A leaf beside :mod:`geoscaler.render.texture`: it imports only :mod:`geoscaler.errors` (and numpy).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from geoscaler.errors import GeoscalerError

COLOR, NORMAL, DATA = "color", "normal", "data"
TEXTURE_CLASSES = (COLOR, NORMAL, DATA)
"""Texture classes: colours (base colour, emissive), tangent-space normals, linear data
(metallic-roughness, occlusion, ARM)."""


def round_ratio(numerator: int, denominator: int) -> int:
    """``numerator / denominator`` rounded half up, in exact integer arithmetic."""
    return (2 * numerator + denominator) // (2 * denominator)


def check_scale(scale: Any) -> int:
    """``scale`` as an int when it is a whole number >= 2 (bools and floats such as 4.0 are
    not); otherwise the one error message for a bad scale, wherever it was given."""
    if isinstance(scale, bool) or not isinstance(scale, int | np.integer) or scale < 2:
        raise GeoscalerError(
            f"--scale {scale!r}: must be a whole number >= 2, e.g. 4 (2048 -> 512) or 8"
        )
    return int(scale)


def nearest_power_of_two(length: int) -> int:
    """The power of two nearest ``length`` >= 1 (ties go up: 3 -> 4, 6 -> 8, 750 -> 512)."""
    lower = 1 << (length.bit_length() - 1)
    return lower if length - lower < 2 * lower - length else 2 * lower


def _floor_power_of_two(length: int) -> int:
    return 1 << (length.bit_length() - 1)


@dataclass(frozen=True)
class SizeRule:
    """How one class of textures is resized.

    Attributes:
        scale: each side divided by this whole number >= 2 (None: not divided).
        max_size: the longer side at most this many texels (None: no limit).
        power_of_two: each side rounded to the nearest power of two (at most ``max_size``).
    """

    scale: int | None = None
    max_size: int | None = None
    power_of_two: bool = False

    def __post_init__(self) -> None:
        if self.scale is not None:
            object.__setattr__(self, "scale", check_scale(self.scale))
        size = self.max_size
        if size is not None:
            if isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 1:
                raise GeoscalerError(f"--max-size {size!r}: must be a whole number >= 1")
            object.__setattr__(self, "max_size", int(size))

    def size(self, height: int, width: int) -> tuple[int, int]:
        """``(h, w)`` texels for a ``height x width`` input, each at least 1 and at most the
        input's side.

        Raises:
            GeoscalerError: ``scale`` is larger than the input's shorter side.
        """
        if height < 1 or width < 1:
            raise GeoscalerError(f"texture size {height} x {width}: both sides must be >= 1")
        h, w = height, width
        if self.scale is not None:
            if self.scale > min(height, width):
                raise GeoscalerError(
                    f"scale {self.scale} is larger than the {height} x {width} texture: its "
                    f"shorter side would drop below 1 texel; use a scale of at most "
                    f"{min(height, width)}"
                )
            h, w = round_ratio(h, self.scale), round_ratio(w, self.scale)
        if self.max_size is not None and max(h, w) > self.max_size:
            longer = max(h, w)
            h = max(round_ratio(h * self.max_size, longer), 1)
            w = max(round_ratio(w * self.max_size, longer), 1)
        if self.power_of_two:
            limit = self.max_size or max(height, width)
            h, w = (min(nearest_power_of_two(s), _floor_power_of_two(limit)) for s in (h, w))
            h = min(h, _floor_power_of_two(height))
            w = min(w, _floor_power_of_two(width))
        return min(h, height), min(w, width)

    @property
    def shrinks(self) -> bool:
        """Whether the rule can make a texture smaller at all."""
        return self.scale is not None or self.max_size is not None or self.power_of_two

    @property
    def label(self) -> int | str:
        """The rule in a report: the scale alone as a number (4), else words ("x4, <= 1024")."""
        if self.scale is not None and self.max_size is None and not self.power_of_two:
            return self.scale
        parts = [f"x{self.scale}"] if self.scale is not None else []
        parts += [f"<= {self.max_size}"] if self.max_size is not None else []
        parts += ["power of two"] if self.power_of_two else []
        return ", ".join(parts) or "kept"


@dataclass(frozen=True)
class SizePlan:
    """One :class:`SizeRule` per texture class."""

    color: SizeRule
    normal: SizeRule
    data: SizeRule

    def rule(self, kind: str) -> SizeRule:
        """The rule of texture class ``kind`` (:data:`TEXTURE_CLASSES`)."""
        if kind not in TEXTURE_CLASSES:
            raise ValueError(f"texture class {kind!r}: one of {', '.join(TEXTURE_CLASSES)}")
        return getattr(self, kind)


def size_plan(
    scale: dict[str, int], max_size: dict[str, int], power_of_two: bool = False
) -> SizePlan:
    """The plan for per-class settings: keys are a class or ``"all"`` (a class's own value wins).

    >>> size_plan({"all": 4, "normal": 2}, {}).normal
    SizeRule(scale=2, max_size=None, power_of_two=False)
    """
    for settings in (scale, max_size):
        unknown = sorted(set(settings) - {"all", *TEXTURE_CLASSES})
        if unknown:
            raise GeoscalerError(
                f"texture class {unknown[0]!r}: use one of {', '.join(TEXTURE_CLASSES)}"
            )
    base = SizeRule(scale.get("all"), max_size.get("all"), power_of_two)
    rules = {
        kind: replace(
            base, scale=scale.get(kind, base.scale), max_size=max_size.get(kind, base.max_size)
        )
        for kind in TEXTURE_CLASSES
    }
    return SizePlan(**rules)


def parse_class_value(text: str) -> tuple[str, int]:
    """``"4"`` -> ``("all", 4)``, ``"normal=2"`` -> ``("normal", 2)``: one ``--scale`` or
    ``--max-size`` value as the command line gives it.

    Raises:
        ValueError: the text is not ``N`` or ``CLASS=N`` (the message says what to write; the
            caller names the flag).
    """
    kind, _, number = text.rpartition("=")
    kind = kind.strip().lower() or "all"
    if kind not in ("all", *TEXTURE_CLASSES):
        raise ValueError(
            f"{text!r}: texture class {kind!r} unknown; write N for every class or CLASS=N "
            f"with CLASS one of {', '.join(TEXTURE_CLASSES)}"
        )
    try:
        value = int(number.strip())
    except ValueError:
        raise ValueError(
            f"{text!r} is not a whole number; write N or CLASS=N, e.g. 4 or normal=2"
        ) from None
    return kind, value
