"""Frames per second of the desktop app while the optimiser trains.

Opens the app on a mesh (default: the 16,384-face ycb_lego_duplo_a of ../shared/data, or the
19,200-face demo asset ``demo_mesh(40)`` when that is absent), starts ``direct`` and, once
optimisation steps run, counts frames for ``--seconds`` in three modes (the window as the app
opens it the first time: 90% of the screen, the default layout; no layout file is kept):

- ``orbit``: the camera turns every frame, so both views (at their size on screen, 2 x 2
  supersampled) are re-rendered every frame: what a user dragging the mouse sees;
- ``still``: the camera rests; only the live texture updates re-render the downsampled view;
- ``idle``: as ``still``, with hello_imgui's idling on as in the app (no input events: frames
  come at its ``fps_idle``), i.e. a user watching the run without touching anything.

Besides frames a second it reports the optimiser's steps a second in each mode: the worker runs
at the lowest CPU priority, so it is what the UI leaves it.

The app's own pacing (at most 60 fps) stays on; in the first two modes hello_imgui's idling is
off so that frames are not throttled for lack of input events. Run it under a display, e.g.::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/bench_app.py
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

DEFAULT_MESH = (
    Path(__file__).resolve().parents[1].parent / "shared/data/ycb_lego_duplo_a/textured.obj"
)


MODES = ("orbit", "still", "idle")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mesh", nargs="?", help=f"mesh file (default {DEFAULT_MESH})")
    parser.add_argument("--seconds", type=float, default=10.0, help="per mode (default 10)")
    parser.add_argument("--views", type=int, default=8, help="validation views (default 8)")
    args = parser.parse_args()

    from imgui_bundle import hello_imgui

    from geoscaler.app.main import App, add_ons
    from geoscaler.app.training import TrainingSettings
    from geoscaler.procedural import demo_mesh
    from geoscaler.protocol import Evaluation

    path = Path(args.mesh) if args.mesh else (DEFAULT_MESH if DEFAULT_MESH.is_file() else None)
    evaluation = Evaluation(views=tuple(range(args.views)))
    settings = TrainingSettings(method="direct", scale=4, time_budget=600.0, evaluation=evaluation)
    app = App(path, Path(os.environ.get("TMPDIR", "/tmp")), settings, demo=lambda: demo_mesh(40))
    frames: dict[str, list[float]] = {mode: [] for mode in MODES}
    steps: dict[str, list[int]] = {mode: [] for mode in MODES}  # the optimiser's, at each frame
    started = {"at": None}

    def gui() -> None:
        if app.session is not None and app.training is None:
            app.start_training()
        app.gui()
        state = app.progress
        if state is None or state.step < 1:
            hello_imgui.get_runner_params().fps_idling.enable_idling = False
            return  # still caching views: measure while steps run
        now = time.perf_counter()
        started["at"] = started["at"] or now
        index = int((now - started["at"]) // args.seconds)
        if index >= len(MODES):
            hello_imgui.get_runner_params().app_shall_exit = True
            return
        mode = MODES[index]
        hello_imgui.get_runner_params().fps_idling.enable_idling = mode == "idle"
        frames[mode].append(now)
        steps[mode].append(state.step)
        if mode == "orbit":
            app.views.orbit.rotate(3.0, 0.0)  # as a mouse drag does
            app.views.moved()

    params = app.runner_params()
    params.callbacks.show_gui = gui
    from imgui_bundle import immapp

    immapp.run(params, add_ons())
    state = app.progress
    session = app.session
    result = {
        "mesh": session.display_path if session else None,
        "faces": len(session.mesh.faces) if session else None,
        "steps_during_run": state.step if state else 0,
        "cpu_count": os.cpu_count(),
    }
    for mode, times in frames.items():
        if len(times) > 1:
            seconds = times[-1] - times[0]
            result[f"fps_{mode}"] = round((len(times) - 1) / seconds, 1)
            result[f"steps_per_s_{mode}"] = round((steps[mode][-1] - steps[mode][0]) / seconds, 2)
    print(json.dumps(result, indent=2))
    if not frames["orbit"]:
        sys.exit("no optimisation step ran: nothing was measured")


if __name__ == "__main__":
    main()
