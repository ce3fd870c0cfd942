"""Mesh files and output files: everything GeoScaler reads from or writes to disk.

The in-memory form is :mod:`geoscaler.mesh`; this package owns the files:

- :mod:`~geoscaler.io.load` / :mod:`~geoscaler.io.save`: :func:`load_mesh`, :func:`save_mesh`
  and :func:`output_files` (every file a save writes);
- :mod:`~geoscaler.io.obj`, :mod:`~geoscaler.io.gltf`: the OBJ + MTL and glTF / GLB formats;
- :mod:`~geoscaler.io.assemble`: joining and welding the parts of a loaded scene;
- :mod:`~geoscaler.io.images`: image decoding (:func:`image_to_texture`) and PNG encoding;
- :mod:`~geoscaler.io.paths`: path safety, for reading (references stay inside the mesh's
  folder) and writing (:func:`check_outputs`, the one output check; :func:`prepare_folder`);
- :mod:`~geoscaler.io.atomic`: atomic writes (:func:`write_atomically`, :func:`save_png`).

Only the names below are public; the modules' other names are internal to this package.
"""

from .atomic import save_png, write_atomically
from .images import image_to_texture
from .load import load_mesh
from .paths import SUPPORTED_SUFFIXES, check_output, check_outputs, prepare_folder
from .save import output_files, save_mesh

__all__ = [
    "SUPPORTED_SUFFIXES",
    "check_output",
    "check_outputs",
    "image_to_texture",
    "load_mesh",
    "output_files",
    "prepare_folder",
    "save_mesh",
    "save_png",
    "write_atomically",
]
