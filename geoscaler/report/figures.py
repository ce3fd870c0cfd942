"""Pictures for people: method comparison sheets and the quality/memory trade-off plot.

Everything here is drawn with numpy and Pillow (no plotting library); inputs are plain arrays,
outputs ``(H, W, 3)`` uint8 RGB images ready for :func:`geoscaler.io.save_png`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import lru_cache

import numpy as np
from PIL import Image, ImageDraw, ImageFont

# A perceptually ordered dark-to-bright ramp (black, purple, red, orange, pale yellow), sampled
# at equal steps; :func:`colormap` interpolates linearly between the anchors.
COLORMAP_ANCHORS = np.array(
    [
        [0, 0, 4],
        [40, 11, 84],
        [101, 21, 110],
        [159, 42, 99],
        [212, 72, 66],
        [245, 125, 21],
        [250, 193, 39],
        [252, 255, 164],
    ],
    dtype=np.float64,
)

# Line colours of the trade-off plot, one per method in order (colour-blind-friendly set).
PALETTE = [
    (0, 114, 178),
    (213, 94, 0),
    (0, 158, 115),
    (204, 121, 167),
    (230, 159, 0),
    (86, 180, 233),
    (120, 120, 120),
    (0, 0, 0),
]

BACKGROUND = (255, 255, 255)
INK = (20, 20, 20)
GRID = (225, 225, 225)


def colormap(values: np.ndarray) -> np.ndarray:
    """Map ``(...)`` floats in ``[0, 1]`` (clipped) to ``(..., 3)`` uint8 RGB on the ramp."""
    x = np.clip(np.nan_to_num(values, nan=0.0), 0.0, 1.0) * (len(COLORMAP_ANCHORS) - 1)
    positions = np.arange(len(COLORMAP_ANCHORS))
    channels = [np.interp(x, positions, COLORMAP_ANCHORS[:, c]) for c in range(3)]
    return np.stack(channels, axis=-1).round().astype(np.uint8)


@lru_cache(maxsize=8)
def font(size: int = 14) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's default font at ``size`` pixels (its fixed bitmap font without FreeType)."""
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError, ImportError):
        return ImageFont.load_default()


def text_width(draw: ImageDraw.ImageDraw, text: str, size: int) -> int:
    """Width in pixels of ``text`` at ``size``."""
    left, _, right, _ = draw.textbbox((0, 0), text, font=font(size))
    return int(right - left)


def label(draw: ImageDraw.ImageDraw, xy: tuple[int, int], text: str, size: int = 14) -> None:
    """White text on a black box at ``xy`` (top-left), readable over any image."""
    left, top, right, bottom = draw.textbbox(xy, text, font=font(size))
    draw.rectangle((left - 3, top - 2, right + 3, bottom + 2), fill=(0, 0, 0))
    draw.text(xy, text, fill=(255, 255, 255), font=font(size))


def downscale(image: np.ndarray, factor: int) -> np.ndarray:
    """``(H, W, ...)`` box-averaged by an integer ``factor`` (H, W divisible by it)."""
    if factor == 1:
        return image
    height, width = image.shape[:2]
    blocks = image.reshape(height // factor, factor, width // factor, factor, *image.shape[2:])
    return blocks.astype(np.float64).mean(axis=(1, 3))


def abs_error(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(H, W)`` mean absolute error over RGB of two uint8 images, in ``[0, 1]``."""
    difference = image[..., :3].astype(np.float64) - reference[..., :3].astype(np.float64)
    return np.abs(difference).mean(axis=-1) / 255.0


def choose_crop(error: np.ndarray, size: int) -> tuple[int, int]:
    """Top-left ``(row, col)`` of the ``size`` square window with the largest total ``error``.

    Args:
        error: ``(H, W)`` non-negative values (e.g. summed over methods); ``H, W >= size``.
    """
    table = np.pad(error.astype(np.float64).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    sums = table[size:, size:] - table[:-size, size:] - table[size:, :-size] + table[:-size, :-size]
    row, col = np.unravel_index(int(np.argmax(sums)), sums.shape)
    return int(row), int(col)


def error_scale(errors: Sequence[np.ndarray], masks: Sequence[np.ndarray]) -> float:
    """Heatmap full-scale value: the 99th percentile of foreground errors, >= 0.02, 2 digits."""
    values = np.concatenate([e[m] for e, m in zip(errors, masks, strict=True)])
    top = float(np.percentile(values, 99)) if values.size else 0.0
    return math.ceil(max(top, 0.02) * 100) / 100


def _colour_bar(tile: int, vmax: float) -> np.ndarray:
    """A ``tile x tile`` legend: the ramp from 0 to ``vmax`` with its end values."""
    canvas = Image.new("RGB", (tile, tile), (0, 0, 0))
    ramp = colormap(np.linspace(0, 1, tile - 40))[None].repeat(24, axis=0)
    canvas.paste(Image.fromarray(ramp), (20, tile // 2 - 12))
    draw = ImageDraw.Draw(canvas)
    draw.text((20, tile // 2 + 18), "0", fill=(255, 255, 255), font=font(13))
    end = f"{vmax:.2f}"
    draw.text(
        (tile - 20 - text_width(draw, end, 13), tile // 2 + 18),
        end,
        fill=(255, 255, 255),
        font=font(13),
    )
    caption = "|error|, sRGB, RGB mean"
    draw.text(
        ((tile - text_width(draw, caption, 13)) // 2, tile // 2 - 36),
        caption,
        fill=(255, 255, 255),
        font=font(13),
    )
    return np.asarray(canvas)


def _tile_image(image: np.ndarray, tile: int) -> Image.Image:
    """A render shrunk (box) to ``tile`` pixels wide."""
    factor = max(1, image.shape[1] // tile)
    small = downscale(image[..., :3], factor).round().astype(np.uint8)
    return Image.fromarray(small).resize((tile, tile), Image.NEAREST)


def _zoom(image: np.ndarray, crop: tuple[int, int, int], tile: int) -> Image.Image:
    """The ``(row, col, size)`` crop of ``image``, enlarged to ``tile`` with nearest pixels."""
    row, col, size = crop
    return Image.fromarray(image[row : row + size, col : col + size, :3]).resize(
        (tile, tile), Image.NEAREST
    )


def comparison_sheet(
    references: Sequence[np.ndarray],
    candidates: Mapping[str, Sequence[np.ndarray]],
    psnr_fg: Mapping[str, Sequence[float]],
    foreground: Sequence[np.ndarray],
    view_titles: Sequence[str],
    column_titles: Sequence[str],
    title: str,
    tile: int = 256,
    crop: int = 128,
) -> np.ndarray:
    """A labelled sheet: per view, three rows of tiles, columns original | each method.

    Rows of a view: the full render (crop marked), a zoom of the crop (nearest-neighbour, so
    texels stay sharp), and the absolute-error heatmap of the full view (the original's column
    holds the heatmap's colour bar). The crop is where the methods' summed error is largest.

    Args:
        references: per view, ``(H, W, 3)`` uint8 render with the original texture.
        candidates: method -> per view ``(H, W, 3)`` uint8 renders.
        psnr_fg: method -> per view PSNR-fg in dB, printed on the tiles.
        foreground: per view ``(H, W)`` bool mask.
        view_titles: per view heading; column_titles: ``1 + len(candidates)`` headings.
        title: the sheet's first line.
        tile: tile side in pixels; crop: crop side in render pixels.

    Returns:
        ``(height, width, 3)`` uint8.
    """
    names = list(candidates)
    gap, head, view_head = 4, 54, 26
    columns = 1 + len(names)
    width = columns * tile + (columns - 1) * gap
    block = view_head + 3 * tile + 2 * gap
    sheet = Image.new("RGB", (width, head + len(references) * (block + gap)), BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    draw.text((4, 4), title, fill=INK, font=font(16))
    for c, heading in enumerate(column_titles):
        draw.text((c * (tile + gap) + 4, 30), heading, fill=INK, font=font(15))
    for v, reference in enumerate(references):
        top = head + v * (block + gap)
        draw.text((4, top + 4), view_titles[v], fill=INK, font=font(14))
        images = [reference] + [candidates[n][v] for n in names]
        errors = [abs_error(candidates[n][v], reference) for n in names]
        vmax = error_scale(errors, [foreground[v]] * len(errors))
        size = min(crop, reference.shape[0], reference.shape[1])
        crop_box = (*choose_crop(np.sum(errors, axis=0), size), size)
        _draw_view(sheet, images, errors, crop_box, vmax, top + view_head, tile, gap)
        zoom = f"zoom {tile / size:g}x"
        label(draw, (6, top + view_head + tile + gap + 6), zoom, size=13)
        for c, name in enumerate(names, start=1):
            label(
                draw,
                (c * (tile + gap) + 6, top + view_head + 6),
                f"PSNR-fg {psnr_fg[name][v]:.2f} dB",
                size=13,
            )
    return np.asarray(sheet)


def _draw_view(
    sheet: Image.Image,
    images: Sequence[np.ndarray],
    errors: Sequence[np.ndarray],
    crop_box: tuple[int, int, int],
    vmax: float,
    top: int,
    tile: int,
    gap: int,
) -> None:
    """Paste one view's three rows (render, zoom, heatmap) at ``top``."""
    draw = ImageDraw.Draw(sheet)
    factor = tile / images[0].shape[1]
    row, col, size = crop_box
    frame = [
        round(col * factor),
        round(row * factor),
        round((col + size) * factor) - 1,
        round((row + size) * factor) - 1,
    ]
    for c, image in enumerate(images):
        left = c * (tile + gap)
        sheet.paste(_tile_image(image, tile), (left, top))
        draw.rectangle(
            [left + frame[0], top + frame[1], left + frame[2], top + frame[3]],
            outline=(0, 220, 255),
            width=2,
        )
        sheet.paste(_zoom(image, crop_box, tile), (left, top + tile + gap))
        heat_top = top + 2 * (tile + gap)
        if c == 0:
            sheet.paste(Image.fromarray(_colour_bar(tile, vmax)), (left, heat_top))
            continue
        factor_px = max(1, images[0].shape[1] // tile)
        heat = colormap(downscale(errors[c - 1], factor_px) / vmax)
        sheet.paste(Image.fromarray(heat).resize((tile, tile), Image.NEAREST), (left, heat_top))
        draw.rectangle(
            [left + frame[0], heat_top + frame[1], left + frame[2], heat_top + frame[3]],
            outline=(0, 220, 255),
            width=2,
        )


def format_bytes(count: float) -> str:
    """``262144`` -> ``"256 KiB"``, ``4194304`` -> ``"4 MiB"`` (binary units)."""
    for unit in ("B", "KiB", "MiB", "GiB"):
        if count < 1024 or unit == "GiB":
            return f"{count:.3g} {unit}"
        count /= 1024
    raise AssertionError("unreachable")


def _nice_step(span: float, target: int = 6) -> float:
    """A 1/2/5 x 10^k tick step giving about ``target`` ticks over ``span``."""
    raw = span / target if span > 0 else 1.0
    power = 10 ** math.floor(math.log10(raw))
    return next(m * power for m in (1, 2, 5, 10) if m * power >= raw)


def tradeoff_plot(
    series: Mapping[str, Sequence[tuple[float, float, str]]],
    title: str,
    x_label: str,
    y_label: str,
    size: tuple[int, int] = (960, 600),
) -> np.ndarray:
    """Quality against memory: one polyline per method over log2-scaled bytes.

    Args:
        series: method -> points ``(bytes, quality, label)``; the label (e.g. ``"x4"``) is
            written once per distinct byte count, at the top; non-finite points are left out.
        title, x_label, y_label: captions.
        size: ``(width, height)`` in pixels.

    Returns:
        ``(height, width, 3)`` uint8.
    """
    clean = {
        name: sorted(p for p in points if p[0] > 0 and math.isfinite(p[1]))
        for name, points in series.items()
    }
    everything = [p for points in clean.values() for p in points]
    width, height = size
    image = Image.new("RGB", size, BACKGROUND)
    draw = ImageDraw.Draw(image)
    draw.text((16, 12), title, fill=INK, font=font(17))
    if not everything:
        draw.text((16, 60), "no finite results to plot", fill=INK, font=font(15))
        return np.asarray(image)
    box = (90, 70, width - 190, height - 80)
    xs = [math.log2(p[0]) for p in everything]
    ys = [p[1] for p in everything]
    x_range = (math.floor(min(xs)) - 0.5, math.ceil(max(xs)) + 0.5)
    y_step = _nice_step(max(ys) - min(ys))
    y_range = (
        math.floor(min(ys) / y_step - 0.5) * y_step,
        math.ceil(max(ys) / y_step + 0.5) * y_step,
    )

    def to_px(nbytes: float, value: float) -> tuple[float, float]:
        fx = (math.log2(nbytes) - x_range[0]) / (x_range[1] - x_range[0])
        fy = (value - y_range[0]) / (y_range[1] - y_range[0])
        return box[0] + fx * (box[2] - box[0]), box[3] - fy * (box[3] - box[1])

    _axes(draw, box, x_range, y_range, y_step, to_px, x_label, y_label)
    for nbytes, text in {(p[0], p[2]) for p in everything}:  # e.g. "x4" once per memory size
        x, _ = to_px(nbytes, y_range[0])
        draw.text((x - text_width(draw, text, 13) / 2, box[1] + 6), text, fill=INK, font=font(13))
    for index, (name, points) in enumerate(clean.items()):
        colour = PALETTE[index % len(PALETTE)]
        pixels = [to_px(p[0], p[1]) for p in points]
        if len(pixels) > 1:
            draw.line(pixels, fill=colour, width=3)
        for x, y in pixels:
            draw.ellipse((x - 5, y - 5, x + 5, y + 5), fill=colour)
        legend_y = box[1] + 8 + index * 24
        draw.line((box[2] + 20, legend_y + 8, box[2] + 50, legend_y + 8), fill=colour, width=3)
        draw.text((box[2] + 58, legend_y), name, fill=INK, font=font(15))
    return np.asarray(image)


def _axes(draw, box, x_range, y_range, y_step, to_px, x_label: str, y_label: str) -> None:
    """Grid, ticks and captions of :func:`tradeoff_plot` (x: powers of two, in bytes)."""
    left, top, right, bottom = box
    for power in range(math.ceil(x_range[0]), math.floor(x_range[1]) + 1):
        x, _ = to_px(2.0**power, y_range[0])
        draw.line((x, top, x, bottom), fill=GRID)
        text = format_bytes(2.0**power)
        draw.text((x - text_width(draw, text, 12) / 2, bottom + 6), text, fill=INK, font=font(12))
    value = y_range[0]
    while value <= y_range[1] + 1e-9:
        _, y = to_px(2.0 ** x_range[0], value)
        draw.line((left, y, right, y), fill=GRID)
        text = f"{value:g}"
        draw.text((left - 8 - text_width(draw, text, 12), y - 7), text, fill=INK, font=font(12))
        value += y_step
    draw.rectangle(box, outline=INK, width=1)
    draw.text(
        ((left + right - text_width(draw, x_label, 14)) / 2, bottom + 30),
        x_label,
        fill=INK,
        font=font(14),
    )
    draw.text((16, top - 22), y_label, fill=INK, font=font(14))
