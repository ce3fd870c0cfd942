"""The app's side windows, one small class each: optimiser controls, live plots, UV inspector,
bookmarks (with A/B metrics) and export. Each ``draw(app)`` reads and changes the UI-editable
:class:`~geoscaler.app.state.AppState` (``app.state``), never attributes of :class:`App` itself,
and asks App for actions (start, export...); none of them blocks the UI thread for long.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import torch
from imgui_bundle import ImVec2, ImVec4, imgui, implot

from geoscaler.methods import is_learned, method_names
from geoscaler.metrics import psnr_fg, ssim_fg
from geoscaler.protocol import VIEWS

from .gl_renderer import use_screen
from .training import SSIM_VIEWS
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


class OptimisePanel:
    """Method, scale, steps or time budget; start / pause / resume / stop; progress."""

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
            changed, steps = imgui.input_int("steps", settings.steps or 0, 10, 100)
            settings.steps = steps if steps > 0 else None
            budget = settings.time_budget or 0.0
            changed, budget = imgui.input_float("time budget (s)", budget, 5.0, 30.0, "%.0f")
            settings.time_budget = budget if budget > 0 else None
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


class PlotsPanel:
    """Loss and validation PSNR-fg against step or time (implot), bicubic as a line."""

    def __init__(self) -> None:
        self.against_time = False

    def draw(self, app: App) -> None:
        imgui.begin("Plots")
        if imgui.radio_button("against step", not self.against_time):
            self.against_time = False
        imgui.same_line()
        if imgui.radio_button("against time (s)", self.against_time):
            self.against_time = True
        state = app.progress
        size = ImVec2((imgui.get_content_region_avail().x - 8) / 2, -1)
        x_label = "seconds" if self.against_time else "step"
        fit = implot.AxisFlags_.auto_fit
        if implot.begin_plot("loss", size):
            implot.setup_axes(x_label, "training loss", fit, fit)
            if state is not None and state.losses:
                xs = state.times if self.against_time else state.steps
                implot.plot_line("loss", np.asarray(xs, float), np.asarray(state.losses, float))
            implot.end_plot()
        imgui.same_line()
        if implot.begin_plot("validation", size):
            implot.setup_axes(x_label, "PSNR-fg (dB)", fit, fit)
            implot.setup_axis(implot.ImAxis_.y2, "SSIM-fg", fit | implot.AxisFlags_.opposite)
            if state is not None and state.validation_psnr:
                xs = state.validation_times if self.against_time else state.validation_steps
                xs = np.asarray(xs, float)
                implot.plot_line("PSNR-fg", xs, np.asarray(state.validation_psnr, float))
                if math.isfinite(state.bicubic_psnr):
                    ys = np.full(len(xs), float(state.bicubic_psnr))
                    implot.plot_line("bicubic PSNR-fg", xs, ys)
                ssim = np.asarray(state.validation_ssim, float)
                if len(ssim):
                    implot.set_axes(implot.ImAxis_.x1, implot.ImAxis_.y2)
                    implot.plot_line(f"SSIM-fg ({SSIM_VIEWS} views)", xs[: len(ssim)], ssim)
            implot.end_plot()
        imgui.end()


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
        if self.warp_texture is not None:
            self.warp_texture.release()
            self.warp_texture = None
        if session.candidate_uvs is not None:
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
        count = 3 if app.session.candidate_uvs is not None else 2
        width = imgui.get_content_region_avail().x
        height = imgui.get_content_region_avail().y - imgui.get_text_line_height_with_spacing()
        side = max(min((width - 8 * count) / count, height), 32)
        if abs(side - self.size) > 16:  # lines stay one texel wide on screen
            self.size, self.drawn_for = int(side), None
        self._update(app)
        assert self.pictures is not None
        imgui.text(f"original, {len(self.outlines)} chart boundary edges")
        imgui.same_line(side + 16)
        imgui.text(f"new: {session.candidate_label}")
        if count == 3:
            imgui.same_line(2 * side + 32)
            imgui.text(f"UV warp, up to {self.warp_max_texels:.1f} texels")
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
