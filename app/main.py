"""``geoscaler view``: the desktop app (glfw window, imgui-bundle UI, moderngl views).

:class:`App` holds what every window reads: the open :class:`Session`, the running
:class:`Training` and its latest :class:`TrainingState`, and the UI-editable
:class:`~geoscaler.app.state.AppState` (settings, export name, errors, messages), which the panels
read and write. Its ``gui`` runs once a frame on the UI thread: it
collects finished work (a mesh loaded, live textures from the optimiser), then draws the
windows. Slow work never runs here: meshes load and methods run on worker threads.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import moderngl
import numpy as np
from imgui_bundle import hello_imgui, imgui, immapp

from geoscaler.clock import WALL_CLOCK
from geoscaler.errors import GeoscalerError
from geoscaler.io import (
    SUPPORTED_SUFFIXES,
    check_output,
    load_mesh,
    prepare_folder,
    save_png,
    write_atomically,
)
from geoscaler.mesh import TexturedMesh
from geoscaler.pipeline.downsampling import Job, check_output_name, export
from geoscaler.pipeline.job import checked_output_sizes
from geoscaler.procedural import demo_mesh
from geoscaler.report.documents import dumps, report_document
from geoscaler.resize.sizes import size_plan

from .panels import BookmarksPanel, ExportPanel, OptimisePanel, Panel, PlotsPanel, UVPanel
from .session import DEMO_NAME, Session
from .state import AppState
from .training import Training, TrainingSettings, TrainingState
from .views import ViewsPanel

WINDOW_SIZE = (1280, 800)
"""The window's size where the screen's cannot be read."""
SCREEN_SHARE = 0.9
"""The share of the screen's width and height (its work area) the window opens at."""
SPLITS = (  # (dock space split, new dock space, side, share of the split space)
    ("MainDockSpace", "Bottom", imgui.Dir.down, 0.32),
    ("MainDockSpace", "Side", imgui.Dir.right, 0.3),
    ("Bottom", "BottomRight", imgui.Dir.right, 0.6),
    ("Side", "SideMiddle", imgui.Dir.down, 0.45),
    ("SideMiddle", "SideLast", imgui.Dir.down, 0.5),
)
"""The docking layout at first start: the views take the free space; right of them the
optimiser over the bookmarks and the export; under them, across the window, the UV inspector
and the plots."""
DOCKS = {  # window -> the dock space (of SPLITS) where it starts
    "Views": "MainDockSpace",
    "Optimise": "Side",
    "Bookmarks": "SideMiddle",
    "Export": "SideLast",
    "UV inspector": "Bottom",
    "Plots": "BottomRight",
}
MAX_FPS = 60.0
"""Frames a second at most: the rest of the time (and the GIL) goes to the optimiser."""
IDLE_FPS = 10.0
"""Frames a second without input events (hello_imgui's idling), training or not: enough for the
plots and the live texture (pulled twice a second), and on 2 cores it leaves the optimiser 3.8
steps a second instead of 1.7 at 30 fps (``benchmarks/bench_app.py``, mode ``idle``)."""


class App:
    """The app's state and frame loop.

    Args:
        mesh_path: the mesh to open first (None: the built-in demo asset).
        out_dir: where exports, screenshots and bookmarks go (created when first needed).
        settings: the optimiser's starting settings.
        demo: builds the demo asset (tests pass a smaller one).
    """

    def __init__(
        self,
        mesh_path: Path | None = None,
        out_dir: Path = Path("."),
        settings: TrainingSettings | None = None,
        demo: Callable[[], TexturedMesh] = demo_mesh,
    ):
        self.first_path = mesh_path
        self.out_dir = Path(out_dir)
        self.state = AppState(settings=settings or TrainingSettings())  # what the panels edit
        self.demo = demo
        self.ctx: moderngl.Context | None = None
        self.session: Session | None = None
        self.training: Training | None = None
        self.progress: TrainingState | None = None  # the optimisation's latest snapshot
        self.shown_version = 0
        self.frames = 0
        self.last_frame = 0.0
        self.loader = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="geoscaler-load")
        self.loading: tuple[Path | None, concurrent.futures.Future] | None = None
        self.dialog = None
        self.views = ViewsPanel()
        self.optimise = OptimisePanel()
        self.plots = PlotsPanel()
        self.uv = UVPanel()
        self.bookmarks = BookmarksPanel()
        self.exporter = ExportPanel()

    # ----------------------------------------------------------------- start-up and files

    def post_init(self) -> None:
        """Called by hello_imgui once the window and its GL context exist."""
        self.ctx = moderngl.create_context()
        self._accept_drops()
        self.open(self.first_path)
        self.wait_for_load()

    def _accept_drops(self) -> None:
        try:
            import glfw
            from imgui_bundle import glfw_utils

            window = glfw_utils.glfw_window_hello_imgui()
            glfw.set_drop_callback(window, lambda _window, paths: self.open(Path(paths[0])))
        except Exception as error:  # no glfw backend: the file dialog still works
            self.state.messages.append(f"drag and drop unavailable: {error}")

    def open(self, path: Path | None) -> None:
        """Load ``path`` (None: the demo asset) on a worker thread; shown once loaded."""
        if path is not None and path.suffix.lower() not in SUPPORTED_SUFFIXES:
            self.state.error = f"cannot open {path}: not a mesh ({', '.join(SUPPORTED_SUFFIXES)})"
            return
        task = self.demo if path is None else (lambda: load_mesh(path))
        self.loading = (path, self.loader.submit(task))

    def wait_for_load(self, timeout: float | None = None) -> None:
        if self.loading is not None:
            concurrent.futures.wait([self.loading[1]], timeout)
            self._collect_load()

    def _collect_load(self) -> None:
        if self.loading is None or not self.loading[1].done():
            return
        path, future = self.loading
        self.loading = None
        try:
            self._show(future.result(), path)
        except Exception as error:  # a bad file must not end the app
            self.state.error = f"cannot open {path or DEMO_NAME}: {error}"

    def _show(self, mesh: TexturedMesh, path: Path | None) -> None:
        checked_output_sizes(mesh, self.state.settings.scale)
        assert self.ctx is not None
        session = Session(self.ctx, mesh, path, self.out_dir, self.state.settings.scale)
        if self.training is not None:
            self.training.stop()
        self.training, self.progress, self.shown_version = None, None, 0
        if self.session is not None:
            self.session.release()
        self.session = session
        self.views.go_home()  # framed on the new mesh
        self.uv.reset()
        scale = self.state.settings.scale
        self.state.export_name = str(self.out_dir / f"{session.name}_x{scale}.glb")
        self.state.messages.append(f"opened {session.display_path}: {len(mesh.faces):,} faces")

    def open_dialog(self) -> None:
        try:
            from imgui_bundle import portable_file_dialogs as pfd

            self.dialog = pfd.open_file(
                "Open a mesh", str(self.out_dir), ["Meshes", "*.obj *.gltf *.glb", "All", "*"]
            )
        except Exception as error:
            self.state.error = f"no file dialog here ({error}); type a path in File > Open path"

    def _collect_dialog(self) -> None:
        if self.dialog is not None and self.dialog.ready():
            files = self.dialog.result()
            self.dialog = None
            if files:
                self.open(Path(files[0]))

    # ----------------------------------------------------------------- actions

    def guard(self, action: Callable[[], object]) -> None:
        """Run a UI action; any error it raises becomes the error line, the app goes on."""
        try:
            action()
        except (GeoscalerError, OSError) as error:
            self.state.error = str(error)
        except Exception as error:
            self.state.error = f"{type(error).__name__}: {error}"

    def set_scale(self, scale: int) -> None:
        assert self.session is not None
        try:
            checked_output_sizes(self.session.mesh, scale)
        except GeoscalerError as error:
            self.state.error = str(error)
            return
        self.state.settings.scale = scale
        if self.progress is None:
            self.session.set_bicubic(scale)
            self.views.dirty = True
        self.state.export_name = str(self.out_dir / f"{self.session.name}_x{scale}.glb")

    def start_training(self) -> None:
        assert self.session is not None
        chosen = self.state.settings
        settings = dataclasses.replace(chosen, optimize=dict(chosen.optimize))
        try:
            self.training = Training(self.session.mesh, settings)
        except GeoscalerError as error:
            self.state.error = str(error)
            return
        self.progress, self.shown_version = None, 0
        self.training.start()

    def _collect_training(self) -> None:
        if self.training is None or self.session is None:
            return
        progress = self.progress = self.training.read()
        if progress.error and self.state.error is None:
            self.state.error = f"the optimisation failed: {progress.error}"
        if progress.textures is None or progress.texture_version == self.shown_version:
            return
        settings = self.training.settings
        label = f"{settings.method} x{settings.scale}, step {progress.step}"
        uvs = progress.uvs
        if progress.result is not None:
            label = f"{settings.method} x{settings.scale} (best, as exported)"
            uvs = progress.result.result.uvs
        self.session.set_candidate(progress.textures, uvs, label, progress.chains)
        self.shown_version = progress.texture_version
        self.views.dirty = True

    def bookmark_view(self) -> None:
        """Bookmark the current camera (saved to the output folder at once)."""
        assert self.session is not None
        prepare_folder(self.out_dir)
        self.session.bookmarks.add(self.views.orbit)

    def export(self) -> list[Path]:
        """Write the mesh with the new textures (the CLI's exporter) and its JSON report."""
        assert self.session is not None and self.training is not None
        done = self.progress.result if self.progress is not None else None
        if done is None:
            raise GeoscalerError("nothing to export yet: run a method first")
        session, training = self.session, self.training
        overwrite = self.state.overwrite
        output = Path(self.state.export_name)
        prepare_folder(output.parent)
        mesh_path = session.mesh_path or Path(DEMO_NAME)
        output = check_output_name(output, mesh_path, overwrite)
        report = output.with_suffix(".json")
        check_output(report, force=overwrite, inputs=[mesh_path, *session.mesh.source_files])
        settings = training.settings
        plan = size_plan({"all": settings.scale}, {})
        job = Job(
            mesh_path,
            session.mesh,
            output,
            plan,
            settings.method,
            training.options,
            overwrite,
            report,
        )
        shipped = done.result.shipped(settings.method)
        written, done.maps = export(session.mesh, done.result, output, plan, shipped, overwrite)
        document = report_document(job, done, training.seconds, written)
        text = _json(document)
        write_atomically(report, lambda tmp: tmp.write_text(text))
        written.append(report)
        self.state.messages.append("wrote " + ", ".join(str(p) for p in written))
        return written

    def screenshot(self) -> Path:
        """Save the two views (original | downsampled) as a new PNG in the output folder."""
        assert self.session is not None
        prepare_folder(self.out_dir)
        (original, _), (candidate, _) = (t.read() for t in self.session.targets)
        gap = np.zeros((original.shape[0], 8, 3), np.uint8)
        picture = np.concatenate([original, gap, candidate], axis=1)
        index = 1
        while (path := self.out_dir / f"{self.session.name}_view_{index}.png").exists():
            index += 1
        save_png(path, picture)
        self.state.messages.append(f"wrote {path}")
        return path

    # ----------------------------------------------------------------- the frame

    def gui(self) -> None:
        self._pace()
        self.frames += 1
        self._collect_load()
        self._collect_dialog()
        self._collect_training()
        if self.session is None:
            imgui.text("loading..." if self.loading else (self.state.error or "no mesh open"))

    def panels(self) -> dict[str, Panel]:
        """The app's windows by title (:data:`DOCKS`'s order)."""
        panels = (self.views, self.optimise, self.bookmarks, self.exporter, self.uv, self.plots)
        return dict(zip(DOCKS, panels, strict=True))

    def _pace(self) -> None:
        """Sleep out the rest of a 1 / MAX_FPS frame."""
        now = WALL_CLOCK.now()
        wait = self.last_frame + 1.0 / MAX_FPS - now
        if wait > 0:
            time.sleep(wait)
        self.last_frame = WALL_CLOCK.now()

    def _menus(self) -> None:
        """The menu bar: File, then hello_imgui's View (windows, the default layout, theme)."""
        if imgui.begin_menu("File"):
            if imgui.menu_item_simple("Open..."):
                self.open_dialog()
            if imgui.menu_item_simple("Open the demo asset"):
                self.open(None)
            imgui.separator()
            imgui.text("Open path (Enter):")
            entered, self.state.open_path = imgui.input_text(
                "##path", self.state.open_path, imgui.InputTextFlags_.enter_returns_true
            )
            if entered and self.state.open_path:
                self.open(Path(self.state.open_path).expanduser())
                imgui.close_current_popup()
            imgui.separator()
            if imgui.menu_item_simple("Quit"):
                hello_imgui.get_runner_params().app_shall_exit = True
            imgui.end_menu()
        hello_imgui.show_view_menu(hello_imgui.get_runner_params())
        if self.session is not None:
            imgui.text_disabled(
                f"  {self.session.display_path}  (drop a mesh file here to open it)"
            )

    def shutdown(self) -> None:
        """Stop the optimiser and wait for it: a phase that cannot be cut short (view caching,
        the final scoring) ends first, so that no worker outlives the interpreter."""
        if self.training is not None:
            self.training.stop()
            self.training.wait()
        self.loader.shutdown(wait=True, cancel_futures=True)

    # ----------------------------------------------------------------- running

    def runner_params(self, layout_file: Path | None = None) -> hello_imgui.RunnerParams:
        """hello_imgui settings of the app's window.

        Args:
            layout_file: where the window's size and the docking layout are kept between runs
                (hello_imgui's ini file); None: not kept, every run starts from
                :func:`default_window_size` and :data:`SPLITS`.
        """
        params = hello_imgui.RunnerParams()
        window = params.app_window_params
        window.window_title = "GeoScaler"
        window.window_geometry.size = default_window_size()
        window.window_geometry.window_size_measure_mode = (
            hello_imgui.WindowSizeMeasureMode.screen_coords
        )
        window.window_geometry.position_mode = hello_imgui.WindowPositionMode.monitor_center
        window.restore_previous_geometry = layout_file is not None
        imgui_params = params.imgui_window_params
        imgui_params.default_imgui_window_type = (
            hello_imgui.DefaultImGuiWindowType.provide_full_screen_dock_space
        )
        imgui_params.show_menu_bar = True
        imgui_params.show_menu_app = imgui_params.show_menu_view = False  # _menus draws them
        params.docking_params = self.docking_params()
        if layout_file is None:
            params.ini_disable = True
        else:
            params.ini_folder_type = hello_imgui.IniFolderType.absolute_path
            params.ini_filename = str(Path(layout_file).resolve())
        params.fps_idling.fps_idle = IDLE_FPS
        params.callbacks.show_gui = self.gui
        params.callbacks.show_menus = self._menus
        params.callbacks.post_init = self.post_init
        params.callbacks.before_exit = self.shutdown
        return params

    def docking_params(self) -> hello_imgui.DockingParams:
        """The windows, docked as :data:`SPLITS` and :data:`DOCKS` say at first start (then as
        the user leaves them); each panel begins and ends its own window."""
        docking = hello_imgui.DockingParams()
        docking.docking_splits = [
            hello_imgui.DockingSplit(space, new, side, share) for space, new, side, share in SPLITS
        ]
        windows = []
        for title, panel in self.panels().items():
            window = hello_imgui.DockableWindow(title, DOCKS[title], self._panel_gui(panel))
            window.call_begin_end = False
            window.can_be_closed = False
            windows.append(window)
        docking.dockable_windows = windows
        return docking

    def _panel_gui(self, panel: Panel) -> Callable[[], None]:
        """Draws ``panel`` once a mesh is open."""

        def draw() -> None:
            if self.session is not None:
                panel.draw(self)

        return draw


def default_window_size() -> tuple[int, int]:
    """:data:`SCREEN_SHARE` of the primary monitor's work area (:data:`WINDOW_SIZE` where it
    cannot be read), in screen coordinates."""
    try:
        import glfw

        if not glfw.init():
            return WINDOW_SIZE
        monitor = glfw.get_primary_monitor()
        _, _, width, height = glfw.get_monitor_workarea(monitor) if monitor else (0, 0, 0, 0)
    except Exception:  # no glfw here: the app's fixed size
        return WINDOW_SIZE
    if width <= 0 or height <= 0:
        return WINDOW_SIZE
    return int(width * SCREEN_SHARE), int(height * SCREEN_SHARE)


def user_layout_file() -> Path:
    """Where ``geoscaler view`` keeps its window size and layout: ``geoscaler/app.ini`` in the
    user's configuration folder (``~/.config`` on Linux)."""
    folder = hello_imgui.ini_folder_location(hello_imgui.IniFolderType.app_user_config_folder)
    return Path(folder) / "geoscaler" / "app.ini"


def add_ons() -> immapp.AddOnsParams:
    return immapp.AddOnsParams(with_implot=True)


def _json(document: dict) -> str:
    return dumps(document) + "\n"


def run(mesh_path: Path | None = None, out_dir: Path = Path("."), **settings) -> None:
    """Open the app on ``mesh_path`` (None: the demo asset); returns when the window closes."""
    app = App(mesh_path, out_dir, TrainingSettings(**settings))
    immapp.run(app.runner_params(user_layout_file()), add_ons())
