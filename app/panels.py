"""The app's side windows, one small class each: optimiser controls, live plots, UV inspector,
bookmarks (with A/B metrics) and export. Each ``draw(app)`` reads and changes the UI-editable
:class:`~geoscaler.app.state.AppState` (``app.state``), never attributes of :class:`App` itself,
and asks App for actions (start, export...); none of them blocks the UI thread for long.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch
from imgui_bundle import ImVec2, ImVec4, imgui, implot

from geoscaler.methods import is_learned, method_names
from geoscaler.protocol import VIEWS
from geoscaler.render.metrics import psnr_fg, ssim_fg
from geoscaler.uv.uvmodes import UV_MODES

from .gl_renderer import use_screen
from .training import SSIM_VIEWS, TrainingSettings, TrainingState
from .uv_inspect import (
    GRID_COLOUR,
    OUTLINE_COLOUR,
    UVPicture,
    chart_outlines,
    heatmap,
    warp_field,
    warp_grid,
)
from .views import AB, FLIP_V, texture_ref

if TYPE_CHECKING:
    from .main import App

RED = ImVec4(1.0, 0.35, 0.3, 1.0)
GREEN = ImVec4(0.5, 1.0, 0.5, 1.0)
AXIS_ROOM = 9.0
"""Font sizes of a plot's width taken by its y axes' labels and ticks."""
EMPTY = (0.0, 1.0)
"""Axis limits of a plot without data."""
NO_LIMIT = "no limit"
"""What the time budget field shows when there is none (the user emptied it)."""
FIELD_FLAGS = imgui.InputTextFlags_.auto_select_all | imgui.InputTextFlags_.chars_decimal


class Panel(Protocol):
    """A window of the app: it draws itself, reading and changing ``app.state``."""

    def draw(self, app: App) -> None: ...


def steps_text(settings: TrainingSettings) -> str:
    """The steps field: the steps the run will stop at, the method's default unless set."""
    limit = settings.step_limit()
    return "method default" if limit is None else str(limit)


def budget_text(settings: TrainingSettings) -> str:
    """The time budget field: the run's seconds, or :data:`NO_LIMIT`."""
    budget = settings.time_budget
    return NO_LIMIT if budget is None else f"{budget:g}"


def read_steps(text: str, settings: TrainingSettings) -> None:
    """Set ``settings.steps`` from the steps field: a whole number >= 1, or empty for the
    method's default (anything else, e.g. half typed, leaves it as it was)."""
    text = text.strip()
    if not text:
        settings.steps = None
    elif text.isdigit() and int(text) >= 1:
        settings.steps = int(text)


def read_budget(text: str, settings: TrainingSettings) -> None:
    """Set ``settings.time_budget`` from its field: positive seconds, or empty (or
    :data:`NO_LIMIT`) for no limit (anything else leaves it as it was)."""
    text = text.strip()
    if not text or text == NO_LIMIT:
        settings.time_budget = None
        return
    try:
        seconds = float(text)
    except ValueError:
        return
    if math.isfinite(seconds) and seconds > 0:
        settings.time_budget = seconds


def run_summary(settings: TrainingSettings) -> str:
    """One line on when a run with ``settings`` stops."""
    limit = settings.step_limit()
    steps = "the method's step limit" if limit is None else f"{limit} steps"
    if settings.steps is None and limit is not None:
        steps += f" ({settings.method}'s default)"
    if settings.time_budget is None:
        return f"stops after {steps}, no time limit"
    return f"stops after {steps} or {settings.time_budget:g} s, whichever comes first"


class OptimisePanel:
    """Method, scale, steps or time budget; start / pause / resume / stop; progress.

    The steps and time budget fields show what the run will use: the method's default steps
    and the CLI's time budget until the user types others; emptying the steps field brings back
    the default, emptying the time budget means no limit (the field then reads "no limit").
    """

    def __init__(self) -> None:
        self.methods = method_names(aliases=False)

    def draw(self, app: App) -> None:
        imgui.begin("Optimise")
        settings = app.state.settings
        busy = app.training is not None and app.training.running
        imgui.begin_disabled(busy)
        index = self.methods.index(settings.method) if settings.method in self.methods else 0
        changed, index = imgui.combo("method", index, self.methods)
        settings.method = self.methods[index]
        changed, scale = imgui.input_int("scale", settings.scale)
        if changed and 2 <= scale <= 64:
            app.set_scale(scale)
        if is_learned(settings.method):
            changed, text = imgui.input_text("steps", steps_text(settings), FIELD_FLAGS)
            if changed:
                read_steps(text, settings)
            imgui.set_item_tooltip("empty it for the method's default")
            changed, text = imgui.input_text("time budget (s)", budget_text(settings), FIELD_FLAGS)
            if changed:
                read_budget(text, settings)
            imgui.set_item_tooltip("empty it for no time limit (Stop ends the run)")
            renderers = ["exact", "soft"]
            _, index = imgui.combo("renderer", renderers.index(settings.renderer), renderers)
            settings.renderer = renderers[index]
            imgui.set_item_tooltip(
                "what the method trains through: exact (as a GPU shows it) or soft (the "
                "paper's soft rasteriser); validation is always exact"
            )
            if settings.method == "direct" and settings.renderer == "exact":
                layouts = list(UV_MODES)
                _, index = imgui.combo("UV layout", layouts.index(settings.uv), layouts)
                settings.uv = layouts[index]
                imgui.set_item_tooltip(
                    "keep the mesh's UVs, repack its charts by the texels the views ask of "
                    "them (every map re-baked), or auto (a trial in each, the better one goes on)"
                )
            imgui.text_disabled(run_summary(settings))
            evaluation = settings.evaluation
            count = len(evaluation.view_indices)
            changed, count = imgui.input_int("validation views", count)
            if changed:
                count = min(max(count, 1), VIEWS)
                views = None if count == VIEWS else tuple(range(count))
                settings.evaluation = replace(evaluation, views=views)
        imgui.end_disabled()
        self._buttons(app, busy)
        self._status(app)
        imgui.end()

    def _buttons(self, app: App, busy: bool) -> None:
        training = app.training
        if not busy and imgui.button("Start"):
            app.start_training()
        if busy and training is not None:
            if training.controller.paused:
                if imgui.button("Resume"):
                    training.resume()
            elif imgui.button("Pause"):
                training.pause()
            imgui.same_line()
            if imgui.button("Stop"):
                training.stop()

    def _status(self, app: App) -> None:
        if app.state.error:
            imgui.text_colored(RED, app.state.error)
            if imgui.small_button("dismiss"):
                app.state.error = None
        state = app.progress
        if state is None:
            imgui.text("not started: the downsampled view shows bicubic")
            return
        imgui.text(f"phase: {state.phase}")
        done, total = state.caching
        if total and state.step == 0 and state.phase.startswith("caching"):
            imgui.progress_bar(done / total, ImVec2(-1, 0), f"views {done}/{total}")
        steps = f"step {state.step}" + (f" / {state.total_steps}" if state.total_steps else "")
        loss = f"   loss {state.losses[-1]:.4g}" if state.losses else ""
        imgui.text(steps + loss)
        if state.validation_ssim:
            imgui.text(f"SSIM-fg on {SSIM_VIEWS} validation views: {state.validation_ssim[-1]:.4f}")
        if math.isfinite(state.best_psnr) and math.isfinite(state.bicubic_psnr):
            imgui.text(
                f"validation PSNR-fg: best {state.best_psnr:.2f} dB, "
                f"bicubic {state.bicubic_psnr:.2f} dB,"
            )
            imgui.same_line()
            imgui.text_colored(GREEN if state.gain > 0 else RED, f"gain {state.gain:+.2f} dB")
        if state.result is not None:
            for row in state.result.rows:
                imgui.text(
                    f"{row['method']:>8}  PSNR-fg {row['psnr_fg']:.2f}  "
                    f"SSIM-fg {row['ssim_fg']:.4f}  gain {row['gain_db']:+.2f}"
                )


def padded(values: Sequence[float], pad: float = 0.08) -> tuple[float, float] | None:
    """Axis limits that hold every finite value of ``values`` with ``pad`` of their span to
    spare either side (a lone value: a small span around it); None without a finite value."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return None
    lo, hi = min(finite), max(finite)
    margin = (hi - lo) * pad or max(abs(hi) * 0.01, 1e-3)
    return lo - margin, hi + margin


def nice_ticks(lo: float, hi: float, count: int) -> list[float]:
    """At most ``count`` round values in ``[lo, hi]``, 1, 2 or 5 times a power of ten apart:
    the closest such spacing that needs no more (so that their labels do not run together)."""
    span = hi - lo
    if not (math.isfinite(span) and span > 0):
        return [lo]
    power = 10.0 ** math.floor(math.log10(span / max(count, 1)))
    for step in (m * power * 10**k for k in range(3) for m in (1, 2, 5)):
        first, last = math.ceil(lo / step), math.floor(hi / step)
        if last - first + 1 <= count:
            return [k * step for k in range(first, last + 1)] or [lo]
    return [lo]


class PlotsPanel:
    """Loss and validation PSNR-fg against step or time (implot), bicubic as a line.

    The axes are fitted here rather than by implot, so that bicubic's level -- the zero of the
    gain -- is always on the PSNR axis; step or time ticks are spaced to their labels' width;
    legends sit outside the plot area, above it, where they hide no curve.

    Attributes:
        validation_limits: ``(low, high)`` of the PSNR axis as implot drew it last frame.
        validation_points: the validations plotted last frame.
    """

    def __init__(self) -> None:
        self.against_time = False
        self.validation_limits: tuple[float, float] | None = None
        self.validation_points = 0

    def draw(self, app: App) -> None:
        imgui.begin("Plots")
        if imgui.radio_button("against step", not self.against_time):
            self.against_time = False
        imgui.same_line()
        if imgui.radio_button("against time (s)", self.against_time):
            self.against_time = True
        state = app.progress
        available = imgui.get_content_region_avail()
        stacked = available.y > 0.6 * available.x  # a tall window: one plot above the other
        if stacked:
            size = ImVec2(available.x, max((available.y - 8) / 2, 120))
        else:
            size = ImVec2(max((available.x - 8) / 2, 160), available.y)
        self._loss(state, size)
        if not stacked:
            imgui.same_line()
        self._validation(state, size)
        imgui.end()

    def _x_axis(self, xs: np.ndarray, width: float) -> None:
        """Fit the step or time axis of a plot ``width`` wide to ``xs``, with as many ticks as
        their labels leave room for."""
        implot.setup_axis(implot.ImAxis_.x1, "seconds" if self.against_time else "step")
        limits = padded(xs.tolist(), 0.02) or EMPTY
        implot.setup_axis_limits(implot.ImAxis_.x1, *limits, implot.Cond_.always)
        label = imgui.calc_text_size(f"{limits[1]:.0f}").x + 2.5 * imgui.get_font_size()
        area = width - AXIS_ROOM * imgui.get_font_size()  # less the y axes' labels
        ticks = nice_ticks(*limits, max(int(area / label), 2))
        implot.setup_axis_ticks(implot.ImAxis_.x1, ticks, [f"{t:g}" for t in ticks])

    def _loss(self, state: TrainingState | None, size: ImVec2) -> None:
        if not implot.begin_plot("loss", size, implot.Flags_.no_legend):
            return
        xs = [] if state is None else (state.times if self.against_time else state.steps)
        xs = np.asarray(xs, float)
        self._x_axis(xs, size.x)
        implot.setup_axis(implot.ImAxis_.y1, "training loss", implot.AxisFlags_.auto_fit)
        if not len(xs):
            implot.setup_axis_limits(implot.ImAxis_.y1, *EMPTY, implot.Cond_.always)
        if state is not None and state.losses:
            implot.plot_line("loss", xs, np.asarray(state.losses, float))
        implot.end_plot()

    def _validation(self, state: TrainingState | None, size: ImVec2) -> None:
        if not implot.begin_plot("validation", size):
            return
        implot.setup_legend(
            implot.Location_.north, implot.LegendFlags_.outside | implot.LegendFlags_.horizontal
        )
        psnr = [] if state is None else state.validation_psnr
        if state is None:
            xs = np.zeros(0)
        else:
            times = self.against_time
            xs = np.asarray(state.validation_times if times else state.validation_steps, float)
        self._x_axis(xs, size.x)
        implot.setup_axis(implot.ImAxis_.y1, "PSNR-fg (dB)")
        implot.setup_axis(implot.ImAxis_.y2, "SSIM-fg", implot.AxisFlags_.opposite)
        reference = math.nan if state is None else state.bicubic_psnr
        limits = padded([*psnr, reference]) or EMPTY
        implot.setup_axis_limits(implot.ImAxis_.y1, *limits, implot.Cond_.always)
        ssim = np.asarray([] if state is None else state.validation_ssim, float)
        ssim_limits = padded(ssim.tolist()) or EMPTY
        implot.setup_axis_limits(implot.ImAxis_.y2, *ssim_limits, implot.Cond_.always)
        marked = implot.Spec(marker=implot.Marker_.circle, marker_size=3)
        if psnr:
            implot.plot_line("PSNR-fg", xs, np.asarray(psnr, float), marked)
        if math.isfinite(reference):
            level = implot.Spec(flags=implot.InfLinesFlags_.horizontal)
            implot.plot_inf_lines("bicubic PSNR-fg", np.asarray([reference], float), level)
        if len(ssim):
            implot.set_axes(implot.ImAxis_.x1, implot.ImAxis_.y2)
            implot.plot_line(f"SSIM-fg ({SSIM_VIEWS} views)", xs[: len(ssim)], ssim, marked)
        shown = implot.get_plot_limits(implot.ImAxis_.x1, implot.ImAxis_.y1).y
        self.validation_limits = (shown.min, shown.max)
        self.validation_points = len(psnr)
        implot.end_plot()


def column_labels(texts: Sequence[str], width: float) -> None:
    """``texts`` on one line, each at the start of a column ``width`` wide (as images placed
    with ``same_line()`` are) and cut at its end, so that a long one does not run into the
    next."""
    draw = imgui.get_window_draw_list()
    start = imgui.get_cursor_screen_pos()
    spacing = imgui.get_style().item_spacing.x
    height = imgui.get_text_line_height()
    colour = imgui.get_color_u32(imgui.Col_.text)
    for index, text in enumerate(texts):
        corner = ImVec2(start.x + index * (width + spacing), start.y)
        draw.push_clip_rect(corner, ImVec2(corner.x + width, corner.y + height), True)
        draw.add_text(corner, colour, text)
        draw.pop_clip_rect()
    imgui.dummy(ImVec2(len(texts) * (width + spacing), height))


def relaid(app: App) -> bool:
    """The candidate is in a repacked layout (``--uv repack`` or ``auto``), not a warp."""
    progress, training = getattr(app, "progress", None), getattr(app, "training", None)
    result = None if progress is None or progress.result is None else progress.result.result
    if result is not None:
        return result.layout is not None
    return training is not None and training.settings.uv != "keep"


class UVPanel:
    """Original and new texture side by side with chart outlines; a warp grid and magnitude
    heatmap for methods that move UVs."""

    def __init__(self) -> None:
        self.material = 0
        self.pictures: tuple[UVPicture, UVPicture] | None = None
        self.warp_texture = None
        self.drawn_for: tuple | None = None
        self.outlines: np.ndarray | None = None
        self.warp_max_texels = 0.0
        self.size = 256  # texels per side of the pictures: the size they are shown at

    def reset(self) -> None:
        self.drawn_for = None
        self.outlines = None
        self.material = 0

    def _update(self, app: App) -> None:
        session = app.session
        key = (id(session), id(session.candidate), self.material)
        if key == self.drawn_for:
            return
        ctx = session.renderer.ctx
        if self.pictures is None or self.pictures[0].size != self.size:
            for picture in self.pictures or ():
                picture.release()
            self.pictures = (UVPicture(ctx, self.size), UVPicture(ctx, self.size))
        if self.outlines is None:
            self.outlines = chart_outlines(session.mesh, self.material)
        m = self.material
        outline = [(self.outlines, OUTLINE_COLOUR)]
        self.pictures[0].draw(session.original.textures[m], outline)
        layers = list(outline)
        if session.candidate_uvs is not None:  # the charts where the candidate's UVs put them
            moved = session.mesh.with_uvs(session.candidate_uvs)
            layers = [(chart_outlines(moved, m), OUTLINE_COLOUR)]
        if self.warp_texture is not None:
            self.warp_texture.release()
            self.warp_texture = None
        if session.candidate_uvs is not None and not relaid(app):
            displacement, covered = warp_field(session.mesh, session.candidate_uvs)
            layers.append((warp_grid(displacement, covered), GRID_COLOUR))
            texture = session.candidate_textures[m]
            texels = max(texture.shape[:2]) if texture is not None else 1
            magnitude = np.linalg.norm(displacement, axis=-1) * texels
            self.warp_max_texels = float(magnitude[covered].max()) if covered.any() else 0.0
            picture = heatmap(magnitude, covered)
            self.warp_texture = ctx.texture(picture.shape[1::-1], 4, picture.tobytes())
        self.pictures[1].draw(session.candidate.textures[m], layers)
        use_screen(ctx)
        self.drawn_for = key

    def draw(self, app: App) -> None:
        imgui.begin("UV inspector")
        session = app.session
        materials = [m.name or f"material {i}" for i, m in enumerate(session.mesh.materials)]
        if len(materials) > 1:
            changed, self.material = imgui.combo("material", self.material, materials)
            if changed:
                self.outlines = None
        count = 3 if app.session.candidate_uvs is not None and not relaid(app) else 2
        width = imgui.get_content_region_avail().x
        height = imgui.get_content_region_avail().y - imgui.get_text_line_height_with_spacing()
        side = max(min((width - 8 * count) / count, height), 32)
        if abs(side - self.size) > 16:  # lines stay one texel wide on screen
            self.size, self.drawn_for = int(side), None
        self._update(app)
        assert self.pictures is not None
        labels = [
            f"original, {len(self.outlines)} chart boundary edges",
            f"new: {session.candidate_label}",
            f"UV warp, up to {self.warp_max_texels:.1f} texels",
        ]
        column_labels(labels[:count], side)
        imgui.image(texture_ref(self.pictures[0].image), ImVec2(side, side), *FLIP_V)
        imgui.same_line()
        imgui.image(texture_ref(self.pictures[1].image), ImVec2(side, side), *FLIP_V)
        if self.warp_texture is not None:
            imgui.same_line()
            imgui.image(texture_ref(self.warp_texture), ImVec2(side, side))
        imgui.end()


class BookmarksPanel:
    """Bookmark the camera, name, jump, A/B with this view's metrics (the selected bookmark is
    ``app.state.bookmark``)."""

    def __init__(self) -> None:
        self.metrics: dict[str, float] | None = None

    def draw(self, app: App) -> None:
        imgui.begin("Bookmarks")
        state = app.state
        bookmarks = app.session.bookmarks
        if imgui.button("Bookmark this view"):
            app.guard(app.bookmark_view)
            state.bookmark = len(bookmarks.items) - 1
        imgui.same_line()
        imgui.text_disabled(str(bookmarks.path))
        for index, bookmark in enumerate(bookmarks.items):
            clicked, _ = imgui.selectable(f"{bookmark.name}##{index}", index == state.bookmark)
            if clicked:
                state.bookmark = index
                self.jump(app, index)
        if 0 <= state.bookmark < len(bookmarks.items):
            bookmark = bookmarks.items[state.bookmark]
            changed, name = imgui.input_text("name", bookmark.name)
            if changed and name:
                app.guard(lambda: bookmarks.rename(state.bookmark, name))
            if imgui.button("Go to"):
                self.jump(app, state.bookmark)
            imgui.same_line()
            if imgui.button("A/B here"):
                self.jump(app, state.bookmark)
                state.view_mode = AB
            imgui.same_line()
            if imgui.button("Delete"):
                app.guard(lambda: bookmarks.remove(state.bookmark))
                state.bookmark = -1
        if self.metrics is not None:
            imgui.text(
                "this view, downsampled vs original (GL renders): "
                f"PSNR-fg {self.metrics['psnr_fg']:.2f} dB, SSIM-fg {self.metrics['ssim_fg']:.4f}"
            )
        imgui.end()

    def jump(self, app: App, index: int) -> None:
        app.views.jump(app.session.bookmarks.items[index].orbit)
        app.views.render(app.session, app.state.view_mode)
        self.metrics = view_metrics(app)


def view_metrics(app: App) -> dict[str, float]:
    """PSNR-fg and SSIM-fg of the downsampled view against the original at the current camera,
    from the two GL renders on screen."""
    (original, foreground), (candidate, _) = (t.read() for t in app.session.targets)
    reference = torch.from_numpy(original).float()[None] / 255
    image = torch.from_numpy(candidate).float()[None] / 255
    mask = torch.from_numpy(foreground)[None]
    if not mask.any():
        return {"psnr_fg": math.nan, "ssim_fg": math.nan}
    return {
        "psnr_fg": float(psnr_fg(image, reference, mask)),
        "ssim_fg": float(ssim_fg(image, reference, mask)),
    }


class ExportPanel:
    """Export the mesh with the new texture and the report, or a screenshot of the views."""

    def draw(self, app: App) -> None:
        imgui.begin("Export")
        state = app.state
        _, state.export_name = imgui.input_text("mesh file", state.export_name)
        _, state.overwrite = imgui.checkbox("replace existing files", state.overwrite)
        ready = app.progress is not None and app.progress.result is not None
        imgui.begin_disabled(not ready)
        if imgui.button("Export mesh + report"):
            app.guard(app.export)
        imgui.end_disabled()
        if not ready:
            imgui.same_line()
            imgui.text_disabled("(run a method first)")
        if imgui.button("Save screenshot"):
            app.guard(app.screenshot)
        for line in state.messages[-6:]:
            imgui.text_wrapped(line)
        imgui.end()
