"""Image files: decoding them into texture arrays and encoding texture arrays as PNG.

Every Pillow image a mesh file brings in becomes a texture through :func:`image_to_texture`
(``(H, W, 3 or 4)`` uint8, row 0 at the top; grey is broadcast with
:func:`geoscaler.texture.to_rgb`). Decoding problems are reported as ``GeoscalerError`` naming
the mesh file that references the image.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.texture import to_rgb

MAX_TEXTURE_SIDE = 16384
"""Widest or tallest texture GeoScaler decodes, in pixels (the largest GPUs' limit)."""
MAX_TEXTURE_PIXELS = 8192 * 8192
"""Most pixels of a texture GeoScaler decodes (268 MB as RGBA): checked from the image's
header, before a byte of it is decompressed, so a small file cannot expand into gigabytes."""


def image_to_texture(image: Image.Image) -> np.ndarray:
    """Convert a Pillow image to the texture layout: ``(H, W, 3 or 4)`` uint8, row 0 at the top.

    Grey (``1``, ``L``) becomes RGB, grey with alpha (``LA``) RGBA, palette (``P``) RGB or RGBA
    when it has transparency, 16-bit grey (``I;16*``, and ``I`` as Pillow reads 16-bit PNGs)
    is scaled by 255/65535 and rounded. Raises ``ValueError`` for float (``F``) images.
    """
    mode = image.mode
    if mode in ("RGB", "RGBA"):
        array = np.asarray(image)
    elif mode in ("1", "L"):
        array = to_rgb(np.asarray(image.convert("L")))
    elif mode == "LA":
        grey_alpha = np.asarray(image)
        array = np.concatenate([to_rgb(grey_alpha[..., 0]), grey_alpha[..., 1:]], axis=2)
    elif mode.startswith("I;16") or mode == "I":
        wide = np.asarray(image).astype(np.float64)
        array = to_rgb(np.round(np.clip(wide, 0, 65535) * (255 / 65535)).astype(np.uint8))
    elif mode in ("P", "PA"):
        transparent = mode == "PA" or "transparency" in image.info
        transparent = transparent or (image.palette is not None and image.palette.mode == "RGBA")
        array = np.asarray(image.convert("RGBA" if transparent else "RGB"))
    elif mode in ("RGBa", "La"):
        array = np.asarray(image.convert("RGBA"))
    elif mode in ("RGBX", "CMYK", "YCbCr", "LAB", "HSV"):
        array = np.asarray(image.convert("RGB"))
    else:
        raise ValueError(f"pixel mode {mode!r} is not supported")
    return np.ascontiguousarray(array, dtype=np.uint8)


def decode_texture(image: Image.Image, label: str, owner: Path) -> np.ndarray:
    """:func:`image_to_texture` with decoding problems reported as ``GeoscalerError``.

    ``label`` names the image in the message, ``owner`` the mesh file that references it.
    """
    check_image_size(image, label, owner)
    try:
        image.load()
        return image_to_texture(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {label} could not be decoded ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def check_image_size(image: Image.Image, label: str, owner: Path) -> None:
    """Refuse an image larger than :data:`MAX_TEXTURE_SIDE` or :data:`MAX_TEXTURE_PIXELS`,
    from its header (nothing is decoded); ``owner`` is the mesh file that references it."""
    width, height = image.size
    if max(width, height) > MAX_TEXTURE_SIDE or width * height > MAX_TEXTURE_PIXELS:
        raise GeoscalerError(
            f"{owner}: texture {label} is {width} x {height} pixels; GeoScaler decodes "
            f"textures of up to {MAX_TEXTURE_PIXELS:,} pixels and {MAX_TEXTURE_SIDE} per side. "
            "Resize it (GeoScaler reduces larger textures to 2048 anyway)."
        )


def open_image_bytes(data: bytes) -> Image.Image:
    """``Image.open`` on bytes without Pillow's own decompression-bomb warning: the size is
    checked by :func:`check_image_size` before decoding, with a message that says what to do."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        return Image.open(io.BytesIO(data))


def open_image(path: Path, owner: Path) -> Image.Image:
    """Open and fully decode an image file, errors as ``GeoscalerError`` naming ``owner``."""
    try:
        image = open_image_bytes(path.read_bytes())
        check_image_size(image, str(path), owner)
        image.load()
        return image
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {path} could not be read as an image ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def png_bytes(pixels: np.ndarray) -> bytes:
    """The PNG file of ``(H, W, C)`` uint8 pixels, ``C`` 3 or 4."""
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()
