"""The two synchronised views: original and downsampled, side by side, wiped, differenced or
toggled A/B, with one orbit camera for both.

Views are re-rendered only when something they show changed (camera, texture, mode), so an
idle window costs almost nothing and the optimiser keeps the CPU. While the camera moves, views
are previews at half the size without supersampling (16 times fewer fragments); the frame after
it stops, they are rendered again in full, at the protocol's 2 x 2 supersampling. When both views
need drawing they are drawn in one pass (:meth:`GLRenderer.render_pair`).
"""

from __future__ import annotations

import math
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
GAP = 8.0
"""Screen units between two views."""
MIN_VIEW = 64.0
"""The smallest side of a view on screen."""
MAX_VIEW_PIXELS = 1024 * 1024
"""The most pixels a view renders (before supersampling): a full-screen view on a 4K monitor
is shown magnified rather than made 4 times as slow."""


def texture_ref(texture: moderngl.Texture) -> imgui.ImTextureRef:
    """An imgui handle of a GL texture."""
    return imgui.ImTextureRef(texture.glo)


class Composer:
    """Wipe and difference pictures of two rendered views of ``shape`` (width, height) pixels,
    in GL (``shaders/compose.frag``)."""

    def __init__(self, ctx: moderngl.Context, shape: tuple[int, int]):
        self.shape = shape
        self.image = ctx.texture(shape, 4)
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


def split_views(
    width: float, height: float, outline: tuple[float, float], label: float = 0.0
) -> tuple[bool, float, float]:
    """How two views, each under a label ``label`` high, share a ``width`` x ``height`` area:
    ``(stacked, view width, view height)``.

    Side by side, unless one above the other shows a mesh whose outline is ``outline``
    ``(width, height)`` larger (a wide mesh). Sizes are whole screen units, so that both views
    cover the same pixels on screen wherever the second one starts.
    """
    across = ((width - GAP) / 2, height - label)
    stacked = (width, (height - GAP) / 2 - label)

    def scale(view: tuple[float, float]) -> float:
        return min(view[0] / outline[0], view[1] / outline[1])

    chosen = stacked if scale(stacked) > scale(across) else across
    return chosen is stacked, whole(chosen[0]), whole(chosen[1])


def whole(size: float) -> float:
    """A view's side in whole screen units, at least :data:`MIN_VIEW`: a fraction would put
    the edges of two views on different pixels (one a pixel wider than the other)."""
    return max(float(math.floor(size)), MIN_VIEW)


def pixel_shape(width: float, height: float, density: float) -> tuple[int, int]:
    """The render size of a view of ``width`` x ``height`` screen units at ``density`` pixels a
    unit: one texel a pixel, shrunk to at most :data:`MAX_VIEW_PIXELS` (then shown magnified)."""
    width, height = width * density, height * density
    shrink = min(1.0, (MAX_VIEW_PIXELS / (width * height)) ** 0.5)
    return max(int(width * shrink), 16), max(int(height * shrink), 16)


class ViewsPanel:
    """The "Views" window.

    The views fill the window: two of them (original, downsampled) side by side, or one above
    the other for a wide mesh; one in the other modes. Each renders at its size on screen, and
    the camera starts framed on the mesh (:meth:`Orbit.frame`), again when the window changes
    shape, until the user moves it.

    Mouse on a view: left drag orbits, right or middle drag (or shift + left) pans, the wheel
    zooms, a double click resets. Space toggles A/B. The mode (side by side, wipe, ...) is
    ``app.state.view_mode``.
    """

    def __init__(self) -> None:
        self.orbit = Orbit()
        self.home = True  # the camera is at its start: framed on the mesh, not moved since
        self.framed_for: tuple | None = None  # (session, aspect) the camera was framed for
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
        self.stacked = False  # the two views are one above the other
        self.view_size = (MIN_VIEW, MIN_VIEW)  # each view's, on screen

    def jump(self, orbit: Orbit) -> None:
        self.orbit = Orbit(*orbit.to_tuple())
        self.home = False
        self.dirty = True

    def go_home(self) -> None:
        """Back to the start view, framed on the mesh at the next frame."""
        self.orbit.reset()
        self.home, self.framed_for = True, None
        self.dirty = True

    def moved(self) -> None:
        """The camera was changed by a drag or the wheel: preview until it rests."""
        self.dirty = self.moving = True
        self.home = False

    def shown(self, session: Session) -> TargetPair:
        """The ``(original, downsampled)`` targets on screen."""
        return session.previews if self.previewing else session.targets

    def render(self, session: Session, mode: int, lit: bool = False) -> None:
        """Draw both views (and the composed picture for ``mode`` wipe or difference) if
        anything changed, as previews while the camera moves, in full once it rests; ``lit``:
        every map under protocol 2's lights."""
        refine = self.previewing and not self.moving
        if not (self.dirty or refine) or session.candidate is None:
            self.moving = False
            return
        self.previewing, self.moving = self.moving, False
        renderer = session.renderer
        camera, pan = self.orbit.camera(), self.orbit.pan
        targets = self.shown(session)
        original, candidate = targets
        key = (id(session), self.orbit.to_tuple(), self.previewing, lit)
        if lit:
            lit_original, lit_candidate = session.lit_surfaces()
            if key != self.original_drawn:
                renderer.render_lit(camera, lit_original, original, pan)
            if lit_candidate is None:  # new UVs: its other maps are not re-baked live
                renderer.render(camera, session.candidate, candidate, pan)
            else:
                renderer.render_lit(camera, lit_candidate, candidate, pan)
        elif key != self.original_drawn:
            renderer.render_pair(camera, (session.original, session.candidate), targets, pan)
        else:  # a new texture alone leaves the original as it is
            renderer.render(camera, session.candidate, candidate, pan)
        self.original_drawn = key
        if mode in (WIPE, DIFFERENCE):
            if self.composer is not None and self.composer.shape != original.shape:
                self.composer.release()
                self.composer = None
            if self.composer is None:
                self.composer = Composer(renderer.ctx, original.shape)
            composed = 0 if mode == WIPE else 1
            self.composer.compose(original.image, candidate.image, composed, self.split, self.gain)
        use_screen(renderer.ctx)
        # Finishing here, before imgui samples the views, measured 2x more frames a second on
        # Mesa llvmpipe than letting the driver interleave the work (16 vs 7.7 fps orbiting).
        renderer.ctx.finish()
        self.dirty = False
        self.renders += 1

    def layout(self, session: Session, mode: int, width: float, height: float) -> None:
        """Size the views to a ``width`` x ``height`` area (labels included) and, while the
        camera is at its start, frame the mesh in them."""
        line = imgui.get_text_line_height_with_spacing()
        if mode == SIDE_BY_SIDE:
            outline = Orbit().outline(session.points)
            self.stacked, view_w, view_h = split_views(width, height, outline, line)
        else:
            self.stacked, view_w, view_h = False, whole(width), whole(height - line)
        density = imgui.get_io().display_framebuffer_scale.x
        if session.set_view_shape(pixel_shape(view_w, view_h, density)):
            self.dirty, self.original_drawn = True, None
        self.view_size = (view_w, view_h)
        aspect = view_w / view_h
        if self.home and self.framed_for != (id(session), round(aspect, 2)):
            self.orbit.frame(session.points, aspect)
            self.framed_for = (id(session), round(aspect, 2))
            self.dirty = True

    def draw(self, app: App) -> None:
        session, state = app.session, app.state
        imgui.begin("Views")
        self._toolbar(state)
        mode = state.view_mode
        available = imgui.get_content_region_avail()
        self.layout(session, mode, available.x, available.y)
        self.render(session, mode, state.lit)
        original, candidate = self.shown(session)
        self.rects.clear()
        view_w = self.view_size[0]
        if mode == SIDE_BY_SIDE:
            name = session.mesh_path.name if session.mesh_path else session.display_path
            start = imgui.get_cursor_pos()
            imgui.text(f"original ({name})")
            self._view("##original", original.image)
            if not self.stacked:  # the second view's label and picture right of the first's
                imgui.set_cursor_pos(ImVec2(start.x + view_w + GAP, start.y))
            imgui.text(f"downsampled: {session.candidate_label}{self._unlit_note(session, state)}")
            if not self.stacked:
                imgui.set_cursor_pos_x(start.x + view_w + GAP)
            self._view("##downsampled", candidate.image)
        elif mode == AB:
            shown = candidate if self.show_candidate else original
            imgui.text(f"B: {session.candidate_label}" if self.show_candidate else "A: original")
            self._view("##ab", shown.image)
        else:
            imgui.text(MODES[mode])
            assert self.composer is not None
            self._view("##composed", self.composer.image)
        imgui.end()
        if (self.moving or self.previewing) and app.training is not None:
            app.training.user_moved()  # the camera moves: the worker holds back

    @staticmethod
    def _unlit_note(session: Session, state: AppState) -> str:
        if state.lit and session.candidate_uvs is not None:
            return " (drawn unlit: its other maps are not re-baked into its new UVs live)"
        return ""

    def _toolbar(self, state: AppState) -> None:
        for index, name in enumerate(MODES):
            if imgui.radio_button(name, state.view_mode == index):
                state.view_mode, self.dirty = index, True
            imgui.same_line()
        changed, state.lit = imgui.checkbox("lit", state.lit)
        if imgui.is_item_hovered():
            imgui.set_tooltip(
                "every map under two lights (protocol 2): normal, roughness and metallic "
                "maps show; off: the base colour unlit (protocol 1)"
            )
        self.dirty |= changed
        imgui.same_line()
        if imgui.button("Reset view"):
            self.go_home()
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

    def _view(self, name: str, texture: moderngl.Texture) -> None:
        """One interactive view of :attr:`view_size`: an invisible button for the mouse, the
        image drawn over it."""
        flags = (
            imgui.ButtonFlags_.mouse_button_left
            | imgui.ButtonFlags_.mouse_button_right
            | imgui.ButtonFlags_.mouse_button_middle
        )
        imgui.invisible_button(name, ImVec2(*self.view_size), flags)
        lo, hi = imgui.get_item_rect_min(), imgui.get_item_rect_max()
        self.rects[name] = (lo.x, lo.y, hi.x, hi.y)
        imgui.get_window_draw_list().add_image(texture_ref(texture), lo, hi, *FLIP_V)
        self._interact()

    def _interact(self) -> None:
        io = imgui.get_io()
        if imgui.is_item_active():
            dx, dy = io.mouse_delta.x, io.mouse_delta.y
            if dx or dy:
                if imgui.is_mouse_down(imgui.MouseButton_.left) and not io.key_shift:
                    self.orbit.rotate(dx, dy)
                else:
                    self.orbit.shift(dx, dy, *self.view_size)
                self.moved()
        if imgui.is_item_hovered():
            if io.mouse_wheel:
                self.orbit.zoom(io.mouse_wheel)
                self.moved()
            if imgui.is_mouse_double_clicked(imgui.MouseButton_.left):
                self.go_home()
