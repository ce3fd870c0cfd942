"""The app's GLSL (``*.vert``, ``*.frag``), installed as package data of ``geoscaler.shaders``.

Read them with ``importlib.resources.files("geoscaler.shaders")``, as
:func:`geoscaler.app.gl_renderer.shader_source` does; no Python code lives here.
"""
