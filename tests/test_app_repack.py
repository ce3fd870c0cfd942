"""The app with ``--uv repack``: the Optimise panel's layout choice reaches the job,
live candidates carry the new layout's UVs, and the UV inspector draws the new layout."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from app_support import gl_context, import_app_module

from geoscaler.protocol import Evaluation

sys.path.insert(0, str(Path(__file__).parent))
from test_atlas import cube_mesh  # noqa: E402


def repacked_run(mesh):
    training = import_app_module("training")
    settings = training.TrainingSettings(
        method="direct",
        scale=4,
        steps=2,
        time_budget=60.0,
        evaluation=Evaluation(image_size=64, views=(0, 30)),
        optimize={"pool_views": 8, "validate_every": 2},
        uv="repack",
    )
    run = training.Training(mesh, settings)
    assert run.options.settings["uv"] == "repack"
    run.start()
    assert run.wait(timeout=300), "the worker did not finish"
    state = run.read()
    assert state.error is None, state.error
    return state


def test_the_app_repacks_and_shows_the_new_layout(tmp_path):
    mesh = cube_mesh(texture_size=256)
    state = repacked_run(mesh)
    result = state.result.result
    assert result.layout is not None and state.result.result.layout_facts.used == "repack"
    assert state.uvs is not None  # the live candidate came with the new layout's UVs
    np.testing.assert_array_equal(state.uvs, result.uvs)

    session_module, panels = import_app_module("session"), import_app_module("panels")
    session = session_module.Session(gl_context(), mesh, None, tmp_path, scale=4, image_size=64)

    class App:  # what UVPanel reads of the app
        pass

    app = App()
    app.session, app.progress, app.training = session, state, None
    session.set_candidate(state.textures, result.uvs, "repacked")
    panel = panels.UVPanel()
    panel._update(app)
    assert panels.relaid(app)
    assert panel.warp_texture is None  # a new layout, not a warp: no warp heatmap
    session.release()
