"""Package layout (metadata is in pyproject.toml).

The library ``geoscaler/`` is found automatically; the desktop app ``app/`` and its GLSL
``shaders/`` live at the top level of the repository and install as ``geoscaler.app`` and
``geoscaler.shaders``.
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["geoscaler*"]), "geoscaler.app", "geoscaler.shaders"],
    package_dir={"geoscaler.app": "app", "geoscaler.shaders": "shaders"},
    package_data={"geoscaler.shaders": ["*.vert", "*.frag"]},
)
