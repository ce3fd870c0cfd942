"""The GeoScaler desktop app (``geoscaler view``), installed as ``geoscaler.app``.

Needs the ``app`` extra (moderngl, glfw, imgui-bundle); the library never imports it. Start with
:func:`geoscaler.app.main.run`; :mod:`geoscaler.app.gl_renderer` is the protocol renderer in
OpenGL and works headless (EGL) too.
"""
