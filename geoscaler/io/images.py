"""Image files: decoding them into texture arrays, and the one encoder of written images.

Every image a mesh file brings in becomes a texture through :func:`image_to_texture`
(``(H, W, 3 or 4)`` uint8, row 0 at the top; grey is broadcast with
:func:`geoscaler.color.to_rgb`) and is kept with its bytes as a
:class:`~geoscaler.mesh.SourceImage` (:func:`source_image`). Decoding problems are reported as
``GeoscalerError`` naming the mesh file that references the image.

Writing (:func:`encoded_image`): a texture that is still its source's array is written as the
source's bytes, verbatim; any other is encoded in its source's format (JPEG stays JPEG at
:data:`JPEG_QUALITY`, PNG stays PNG, WebP stays WebP) or in the format asked, never alpha in a
JPEG. Encodings are memoised, so asking for the bytes again after a save costs nothing.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
import weakref
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from PIL import Image

from geoscaler.color import to_rgb
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import SourceImage

from .paths import safe_characters

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
    with decoding_errors(label, owner):
        image.load()
        return image_to_texture(image)


@contextlib.contextmanager
def decoding_errors(label: str, owner: Path) -> Iterator[None]:
    """Pillow's decoding errors as one ``GeoscalerError``: texture ``label`` of mesh file
    ``owner`` could not be decoded, and what to do."""
    try:
        yield
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


def open_image(path: Path, owner: Path) -> tuple[Image.Image, bytes]:
    """Open and fully decode an image file, errors as ``GeoscalerError`` naming ``owner``;
    returns the image and the file's bytes."""
    try:
        data = path.read_bytes()
        image = open_image_bytes(data)
        check_image_size(image, str(path), owner)
        image.load()
        return image, data
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise GeoscalerError(
            f"{owner}: texture {path} could not be read as an image ({exc}). "
            "Re-save it as an 8-bit PNG or JPEG."
        ) from exc


def open_embedded(data: bytes, label: str, owner: Path) -> Image.Image:
    """:func:`open_image_bytes` for an image inside a mesh file (glTF), errors as
    ``GeoscalerError`` naming ``owner``; decoded by :func:`source_image`."""
    with decoding_errors(label, owner):
        return open_image_bytes(data)


def source_image(
    image: Image.Image, data: bytes, label: str, owner: Path, name: str
) -> SourceImage:
    """Decode an opened image (:func:`decode_texture`) into a read-only texture and keep it
    with its bytes, its type (from the bytes, not from what a file claims) and ``name``."""
    pixels = decode_texture(image, label, owner)
    pixels.flags.writeable = False
    mime = Image.MIME.get(image.format or "", "application/octet-stream")
    return SourceImage(pixels, mime, data, file_stem(name) or "texture")


_IMAGE_SUFFIXES = re.compile(r"\.(png|jpe?g|webp|bmp|tga|tiff?|gif|ktx2?|dds)$", re.IGNORECASE)
MAX_NAME = 64
"""Longest file-name stem kept from an input image's name (the output's stem is added)."""


def file_stem(name: str) -> str:
    """A safe file-name stem from an image's name or file name: the last path component, an
    image suffix dropped, in ASCII letters, digits, ``.``, ``_`` and ``-``
    (:func:`geoscaler.io.paths.safe_characters`), no leading ``.`` or ``-``, at most
    :data:`MAX_NAME` characters; empty where nothing of it is left."""
    last = name.replace("\\", "/").rsplit("/", 1)[-1]
    stem = safe_characters(_IMAGE_SUFFIXES.sub("", last.strip())).lstrip(".-")[:MAX_NAME]
    return stem if stem.strip("_") else ""


# ----------------------------------------------------------------------------- writing

IMAGE_FORMATS = {"png": "image/png", "jpeg": "image/jpeg", "webp": "image/webp"}
"""The formats GeoScaler writes (``image_format`` values) and their MIME types."""
FILE_SUFFIXES = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp"}
"""The file-name suffix of each written MIME type."""
PNG_OPTIMIZE_MAX_TEXELS = 1024 * 1024
"""PNGs of up to this many texels are encoded with Pillow's ``optimize``: about 3% smaller
files for 4 to 7 times the encoding time (2-core machine: a 2048 x 2048 RGB scan texture
0.5 s -> 2.5 s, 4096 x 4096 1.6 s -> 12 s), which larger images would take from the job's
time budget."""
JPEG_QUALITY = 90
"""Pillow quality of every JPEG GeoScaler encodes. Chroma subsampling: a JPEG source's own
(4:2:0 for Poly Haven's maps), 4:2:0 where the source was not a JPEG."""
WEBP_QUALITY = 90
"""Pillow quality of encoded WebP images: lossy where the source was lossy (JPEG, lossy WebP),
lossless (``quality`` is then the effort, transparent texels' colour kept) otherwise."""
_PILLOW_FORMATS = {"image/png": "PNG", "image/jpeg": "JPEG", "image/webp": "WEBP"}
ENCODING_SECONDS_PER_TEXEL = 1.0e-6
"""An upper bound on the seconds :func:`encoded_image` takes a texel, whatever the format, for
images of :data:`PNG_OPTIMIZE_MAX_TEXELS` or fewer: the slowest of its encoders there, PNG
with ``optimize`` and lossless WebP, took 0.9 to 1.0 microseconds a texel on the 2-core AMD
dev machine (a scan texture at 256 to 1024 a side; JPEG 0.01, lossy WebP 0.07 to 0.5)."""
LARGE_ENCODING_SECONDS_PER_TEXEL = 0.5e-6
"""As :data:`ENCODING_SECONDS_PER_TEXEL` for larger images (PNG without ``optimize``: 0.11,
lossless WebP: 0.48 microseconds a texel at 2048 a side)."""


def encoding_seconds(height: int, width: int) -> float:
    """An upper bound on the seconds :func:`encoded_image` takes for a ``height`` x ``width``
    image on the machine its rates were measured on, whatever the format."""
    texels = height * width
    if texels <= PNG_OPTIMIZE_MAX_TEXELS:
        return texels * ENCODING_SECONDS_PER_TEXEL
    return texels * LARGE_ENCODING_SECONDS_PER_TEXEL


def _check_format(image_format: str | None) -> None:
    if image_format is not None and image_format not in IMAGE_FORMATS:
        raise ValueError(
            f"image_format must be one of {', '.join(IMAGE_FORMATS)} or None, got {image_format!r}"
        )


def is_verbatim(pixels: np.ndarray, source: SourceImage | None, image_format: str | None) -> bool:
    """Whether :func:`encoded_image` writes the source's bytes as they were read: the texture
    is the source's very array, the source is PNG, JPEG or WebP and no other format is asked."""
    _check_format(image_format)
    return (
        source is not None
        and pixels is source.pixels
        and source.mime in FILE_SUFFIXES
        and (image_format is None or IMAGE_FORMATS[image_format] == source.mime)
    )


def written_mime(pixels: np.ndarray, source: SourceImage | None, image_format: str | None) -> str:
    """The MIME type :func:`encoded_image` writes ``pixels`` as (without encoding anything):
    the source's when verbatim; else ``image_format``, or the source's format when none is
    asked (PNG without a source, or for a source in another format); PNG instead of JPEG
    for pixels with alpha (``C`` 2 or 4)."""
    if is_verbatim(pixels, source, image_format):
        return source.mime
    if image_format is not None:
        mime = IMAGE_FORMATS[image_format]
    else:
        mime = source.mime if source is not None and source.mime in FILE_SUFFIXES else "image/png"
    if mime == "image/jpeg" and pixels.shape[2] in (2, 4):
        return "image/png"  # JPEG holds no alpha
    return mime


_MEMO: dict[tuple[int, str, int], tuple[weakref.ref, int, bytes]] = {}


def encoded_image(
    pixels: np.ndarray, source: SourceImage | None, image_format: str | None = None
) -> tuple[bytes, str]:
    """The image file of ``(H, W, C)`` uint8 ``pixels`` (``C`` 1 to 4) as GeoScaler writes it,
    and its MIME type.

    ``source`` is where the texture came from (None: made in code); ``image_format`` is
    ``"png"``, ``"jpeg"``, ``"webp"`` or None (each image in its source's format). The rules
    are :func:`is_verbatim` and :func:`written_mime`; the settings :data:`JPEG_QUALITY`,
    :data:`WEBP_QUALITY` and :data:`PNG_OPTIMIZE_MAX_TEXELS`. Grey pixels (equal RGB) are
    written as grey images. Results are memoised per ``(id(pixels), type, source)`` while ``pixels``
    lives and its content is unchanged (a checksum is compared), so asking again after a save
    returns the same bytes without encoding twice.
    """
    if is_verbatim(pixels, source, image_format):
        return source.data, source.mime
    mime = written_mime(pixels, source, image_format)
    key = (id(pixels), mime, id(source))
    checksum = zlib.crc32(np.ascontiguousarray(pixels))
    hit = _MEMO.get(key)
    if hit is not None and hit[0]() is pixels and hit[1] == checksum:
        return hit[2], mime
    data = _encode(pixels, source, mime)
    if hit is None:
        weakref.finalize(pixels, _MEMO.pop, key, None)
    _MEMO[key] = (weakref.ref(pixels), checksum, data)
    return data, mime


def _encode(pixels: np.ndarray, source: SourceImage | None, mime: str) -> bytes:
    channels = pixels.shape[2]
    if channels >= 3 and _is_grey(pixels):
        pixels = pixels[..., [0, 3]] if channels == 4 else pixels[..., :1]
    image = Image.fromarray(
        np.ascontiguousarray(pixels[..., 0] if pixels.shape[2] == 1 else pixels)
    )
    options: dict = {}
    if mime == "image/png":
        options = {"optimize": pixels.shape[0] * pixels.shape[1] <= PNG_OPTIMIZE_MAX_TEXELS}
    elif mime == "image/jpeg":
        options = {"quality": JPEG_QUALITY, "subsampling": _jpeg_sampling(source), "optimize": True}
    else:
        lossless = source is None or not _is_lossy(source)
        options = {"quality": WEBP_QUALITY, "lossless": lossless, "exact": lossless}
    buffer = io.BytesIO()
    image.save(buffer, format=_PILLOW_FORMATS[mime], **options)
    return buffer.getvalue()


def _is_grey(pixels: np.ndarray) -> bool:
    return bool(
        (pixels[..., 0] == pixels[..., 1]).all() and (pixels[..., 1] == pixels[..., 2]).all()
    )


def _jpeg_sampling(source: SourceImage | None) -> int:
    """Pillow's ``subsampling`` (0: 4:4:4, 1: 4:2:2, 2: 4:2:0) of a JPEG source, else 2."""
    if source is None or source.mime != "image/jpeg":
        return 2
    from PIL import JpegImagePlugin

    sampling = JpegImagePlugin.get_sampling(open_image_bytes(source.data))
    return sampling if sampling in (0, 1, 2) else 2


def _is_lossy(source: SourceImage) -> bool:
    """JPEG, or a WebP whose image chunk is ``VP8 `` (lossy) rather than ``VP8L`` (lossless)."""
    if source.mime != "image/webp":
        return source.mime == "image/jpeg"
    data, offset = source.data, 12  # RIFF header: "RIFF", size, "WEBP"
    while offset + 8 <= len(data):
        kind, size = (
            data[offset : offset + 4],
            int.from_bytes(data[offset + 4 : offset + 8], "little"),
        )
        if kind in (b"VP8 ", b"VP8L"):
            return kind == b"VP8 "
        offset += 8 + size + (size & 1)
    return False
