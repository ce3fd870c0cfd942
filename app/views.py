"""The two synchronised views: original and downsampled, side by side, wiped, differenced or
toggled A/B, with one orbit camera for both.

Views are re-rendered only when something they show changed (camera, texture, mode), so an
idle window costs almost nothing and the optimiser keeps the CPU. While the camera moves, views
are previews at half the size without supersampling (16 times fewer fragments); the frame after
it stops, they are rendered again in full, at the protocol's 2 x 2 supersampling. When both views
need drawing they are drawn in one pass (:meth:`GLRenderer.render_pair`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import moderngl
from imgui_bundle import ImVec2, imgui

from .gl_renderer import TargetPair, program, use_screen
from .orbit import Orbit
from .session import Session

if TYPE_CHECKING:
    from .main import App
    from .state import AppState

MODES = ("side by side", "wipe", "difference", "A/B")
SIDE_BY_SIDE, WIPE, DIFFERENCE, AB = range(len(MODES))
FLIP_V = (ImVec2(0, 1), ImVec2(1, 0))  # GL textures are bottom-up, imgui draws top-down


def texture_ref(texture: moderngl.Texture) -> imgui.ImTextureRef:
    """An imgui handle of a GL texture."""
    return imgui.ImTextureRef(texture.glo)


class Composer:
    """Wipe and difference pictures of two rendered views, in GL (``shaders/compose.frag``)."""

    def __init__(self, ctx: moderngl.Context, size: int):
        self.image = ctx.texture((size, size), 4)
        self.fbo = ctx.framebuffer([self.image])
        self.program = program(ctx, "fullscreen.vert", "compose.frag")
        self.vao = ctx.vertex_array(self.program, [])

    def compose(
        self,
        first: moderngl.Texture,
        second: moderngl.Texture,
        mode: int,
        split: float,
        gain: float,
    ) -> None:
        """``mode`` 0: wipe at ``split`` (fraction of the width); 1: difference times ``gain``."""
        self.fbo.use()
        first.use(0)
        second.use(1)
        self.program["first"], self.program["second"] = 0, 1
        self.program["mode"] = mode
        self.program["split"] = split
        self.program["gain"] = gain
        self.vao.render(moderngl.TRIANGLES, vertices=3)

    def release(self) -> None:
        for thing in (self.fbo, self.image, self.vao):
            thing.release()


class ViewsPanel:
    """The "Views" window.

    Mouse on a view: left drag orbits, right or middle drag (or shift + left) pans, the wheel
    zooms, a double click resets. Space toggles A/B. The mode (side by side, wipe, ...) is
    ``app.state.view_mode``.
    """

    def __init__(self) -> None:
        self.orbit = Orbit()
        self.split = 0.5
        self.gain = 4.0
        self.show_candidate = True  # the A/B toggle: B is the downsampled view
        self.dirty = True
        self.moving = False  # the camera moved this frame: render previews
        self.previewing = False  # the views on screen are previews
        self.original_drawn: tuple | None = None  # what the original view shows
        self.composer: Composer | None = None
        self.renders = 0
        self.rects: dict[str, tuple[float, float, float, float]] = {}  # screen rect per view

    def jump(self, orbit: Orbit) -> None:
        self.orbit = Orbit(*orbit.to_tuple())
        self.dirty = True

    def moved(self) -> None:
        """The camera was changed by a drag or the wheel: preview until it rests."""
        self.dirty = self.moving = True

    def shown(self, session: Session) -> TargetPair:
        """The ``(original, downsampled)`` targets on screen."""
        return session.previews if self.previewing else session.targets

    def render(self, session: Session, mode: int) -> None:
        """Draw both views (and the composed picture for ``mode`` wipe or difference) if
        anything changed, as previews while the camera moves, in full once it rests."""
        refine = self.previewing and not self.moving
        if not (self.dirty or refine) or session.candidate is None:
            self.moving = False
            return
        self.previewing, self.moving = self.moving, False
        renderer = session.renderer
        camera, pan = self.orbit.camera(), self.orbit.pan
        targets = self.shown(session)
        original, candidate = targets
        key = (id(session), self.orbit.to_tuple(), self.previewing)
        if key != self.original_drawn:
            renderer.render_pair(camera, (session.original, session.candidate), targets, pan)
            self.original_drawn = key
        else:  # a new texture alone leaves the original as it is
            renderer.render(camera, session.candidate, candidate, pan)
        if mode in (WIPE, DIFFERENCE):
            if self.composer is None:
                self.composer = Composer(renderer.ctx, renderer.image_size)
            composed = 0 if mode == WIPE else 1
            self.composer.compose(original.image, candidate.image, composed, self.split, self.gain)
        use_screen(renderer.ctx)
        # Finishing here, before imgui samples the views, measured 2x more frames a second on
        # Mesa llvmpipe than letting the driver interleave the work (16 vs 7.7 fps orbiting).
        renderer.ctx.finish()
        self.dirty = False
        self.renders += 1

    def draw(self, app: App) -> None:
        session, state = app.session, app.state
        imgui.begin("Views")
        self._toolbar(state)
        mode = state.view_mode
        self.render(session, mode)
        width = imgui.get_content_region_avail().x
        height = imgui.get_content_region_avail().y - imgui.get_text_line_height_with_spacing()
        original, candidate = self.shown(session)
        self.rects.clear()
        if mode == SIDE_BY_SIDE:
            side = max(min((width - 8) / 2, height), 64)
            imgui.text(f"original ({session.display_path})")
            imgui.same_line(side + 16)
            imgui.text(f"downsampled: {session.candidate_label}")
            self._view("##original", original.image, side)
            imgui.same_line()
            self._view("##downsampled", candidate.image, side)
        else:
            side = max(min(width, height), 64)
            if mode == AB:
                shown = candidate if self.show_candidate else original
                label = f"B: {session.candidate_label}" if self.show_candidate else "A: original"
                imgui.text(label)
                self._view("##ab", shown.image, side)
            else:
                imgui.text(MODES[mode])
                assert self.composer is not None
                self._view("##composed", self.composer.image, side)
        imgui.end()

    def _toolbar(self, state: AppState) -> None:
        for index, name in enumerate(MODES):
            if imgui.radio_button(name, state.view_mode == index):
                state.view_mode, self.dirty = index, True
            imgui.same_line()
        if imgui.button("Reset view"):
            self.orbit.reset()
            self.dirty = True
        if state.view_mode == WIPE:
            changed, self.split = imgui.slider_float("split", self.split, 0.0, 1.0)
            self.dirty |= changed
        elif state.view_mode == DIFFERENCE:
            changed, self.gain = imgui.slider_float("gain", self.gain, 1.0, 50.0, "x%.0f")
            self.dirty |= changed
        elif state.view_mode == AB:
            if imgui.button("A/B (space)"):
                self.show_candidate = not self.show_candidate
        if (
            state.view_mode == AB
            and imgui.is_key_pressed(imgui.Key.space)
            and not imgui.get_io().want_text_input
        ):
            self.show_candidate = not self.show_candidate

    def _view(self, name: str, texture: moderngl.Texture, side: float) -> None:
        """One interactive view: an invisible button for the mouse, the image drawn over it."""
        flags = (
            imgui.ButtonFlags_.mouse_button_left
            | imgui.ButtonFlags_.mouse_button_right
            | imgui.ButtonFlags_.mouse_button_middle
        )
        imgui.invisible_button(name, ImVec2(side, side), flags)
        lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.rects[name] = (lo.x, lo.y, hi.x, hi.y)
        imgui.get_window_draw_list().add_image(texture_ref(texture), lo, hi, *FLIP_V)
        self._interact(side)

    def _interact(self, side: float) -> None:
        io = imgui.get_io()
        if imgui.is_item_active():
            dx, dy = io.mouse_delta.x, io.mouse_delta.y
            if dx or dy:
                if imgui.is_mouse_down(imgui.MouseButton_.left) and not io.key_shift:
                    self.orbit.rotate(dx, dy)
                else:
                    self.orbit.shift(dx, dy, side)
                self.moved()
        if imgui.is_item_hovered():
            if io.mouse_wheel:
                self.orbit.zoom(io.mouse_wheel)
                self.moved()
            if imgui.is_mouse_double_clicked(imgui.MouseButton_.left):
                self.orbit.reset()
                self.dirty = True
