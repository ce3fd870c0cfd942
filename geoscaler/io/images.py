"""Image files: decoding them into texture arrays and encoding texture arrays as PNG.

Every Pillow image a mesh file brings in becomes a texture through :func:`image_to_texture`
(``(H, W, 3 or 4)`` uint8, row 0 at the top; grey is broadcast with
:func:`geoscaler.texture.to_rgb`). Decoding problems are reported as ``GeoscalerError`` naming
the mesh file that references the image.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.errors import GeoscalerError
from geoscaler.texture import to_rgb


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
    try:
        image.load()
        return image_to_texture(image)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {label} could not be decoded ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def open_image(path: Path, owner: Path) -> Image.Image:
    """Open and fully decode an image file, errors as ``GeoscalerError`` naming ``owner``."""
    try:
        with Image.open(path) as image:
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
