"""The protocols of PROTOCOL.md in one place: every constant of the evaluation, and the
settings object that says how closely a run follows it.

A leaf: it imports nothing from geoscaler, so every layer may read it.

- Images: ``IMAGE_SIZE`` x ``IMAGE_SIZE`` pixels, ``SUPERSAMPLE`` x ``SUPERSAMPLE`` samples per
  pixel box-averaged, a ``FOV_Y_DEGREES`` vertical field of view.
- View sets: ``VIEWS`` directions of a Fibonacci sphere, at ``VALIDATION_DISTANCE`` (the
  validation set Q), ``NEAR_DISTANCE`` and ``FAR_DISTANCE`` (the robustness sets).
- ``RANGE_S``: the distances of the protocol's training range S (directions uniform on the
  sphere). A method may train on a wider range; its loop's own default is its own constant.
- References: originals larger than ``REFERENCE_MAX_SIZE`` on their longer side are reduced to
  it with Lanczos before evaluation (an evaluation convention, not a product limit).
- Gains are PSNR-fg minus ``GAIN_REFERENCE``'s; texture memory is ``BYTES_PER_TEXEL`` bytes a
  texel (uncompressed RGBA8; GPUs pad RGB8 to RGBA8), mip chain not counted.
- Protocol 2 (lit): the key and fill lights (``KEY_LIGHT``, ``FILL_LIGHT``), the ambient
  ``AMBIENT_RADIANCE`` and the smallest perceptual roughness ``MIN_PERCEPTUAL_ROUGHNESS``;
  everything else is protocol 1's, but references are never reduced.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

PROTOCOL = 1
"""The protocol's version, written into every report."""

IMAGE_SIZE = 512
SUPERSAMPLE = 2
FOV_Y_DEGREES = 45.0

VIEWS = 60
VALIDATION_DISTANCE = 2.4
NEAR_DISTANCE = 1.5
FAR_DISTANCE = 4.0
RANGE_S = (1.8, 3.0)

REFERENCE_MAX_SIZE = 2048
GAIN_REFERENCE = "bicubic"
BYTES_PER_TEXEL = 4

# Protocol 2 (lit materials). Lights follow the camera: ``(up share, right share, irradiance)``
# of the key and fill lights, whose directions are ``normalize(d + up c_up + right c_right)``.
KEY_LIGHT = (0.5, -0.5, 2.0)
FILL_LIGHT = (-0.3, 0.8, 0.6)
AMBIENT_RADIANCE = 0.15
MIN_PERCEPTUAL_ROUGHNESS = 0.05


@dataclass(frozen=True)
class Evaluation:
    """How views are rendered and which of them stand for each view set.

    The default is protocol 1. Smaller images or fewer views make quick checks (tests, the
    app's live preview); their figures are not protocol-1 means, and :attr:`is_protocol` says so.

    Attributes:
        image_size: side of the rendered images, pixels.
        supersample: samples per pixel side (2: 2 x 2 samples box-averaged).
        views: protocol view indices (0 .. ``VIEWS - 1``) standing for every view set, or None
            for all of them.
        reference_max_size: originals longer than this are reduced to it before they are
            rendered (:data:`REFERENCE_MAX_SIZE`); None renders the originals as they are,
            as a downsampling job does (the product optimises against the full resolution).
    """

    image_size: int = IMAGE_SIZE
    supersample: int = SUPERSAMPLE
    views: tuple[int, ...] | None = None
    reference_max_size: int | None = REFERENCE_MAX_SIZE

    def __post_init__(self) -> None:
        if self.image_size < 1 or self.supersample < 1:
            raise ValueError(f"image size and supersampling must be >= 1: {self}")
        if self.reference_max_size is not None and self.reference_max_size < 1:
            raise ValueError(f"reference_max_size must be >= 1 or None: {self}")
        if self.views is not None:
            if not self.views or any(not 0 <= i < VIEWS for i in self.views):
                raise ValueError(f"views must be a non-empty subset of 0..{VIEWS - 1}: {self}")

    @classmethod
    def quick(cls, views: Sequence[int] = (0,), image_size: int = 128) -> Evaluation:
        """A cheap evaluation for checks: ``views`` only, ``image_size`` pixels."""
        return cls(image_size=image_size, views=tuple(views))

    @property
    def view_indices(self) -> list[int]:
        """The protocol view indices of each view set."""
        return list(range(VIEWS)) if self.views is None else list(self.views)

    @property
    def is_protocol(self) -> bool:
        """Whether figures measured with these settings are protocol-1 figures."""
        return self == Evaluation()


PROTOCOL_EVALUATION = Evaluation()
