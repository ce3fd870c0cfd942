"""Mesh files and output files: everything GeoScaler reads from or writes to disk.

The in-memory form is :mod:`geoscaler.mesh`; this package owns the files:

- :mod:`~geoscaler.io.load` / :mod:`~geoscaler.io.save`: :func:`load_mesh`, :func:`save_mesh`
  and :func:`output_files` (every file a save writes);
- :mod:`~geoscaler.io.obj`: the OBJ + MTL format (:mod:`~geoscaler.io.obj_geometry`: its
  geometry, read by trimesh, imported only when an OBJ is read);
  :mod:`~geoscaler.io.gltf` (reading), :mod:`~geoscaler.io.gltf_check`,
  :mod:`~geoscaler.io.gltf_scene` (geometry) and :mod:`~geoscaler.io.gltf_write`: the glTF /
  GLB format; :mod:`~geoscaler.io.slots`: how texture slots are named in each;
- :mod:`~geoscaler.io.assemble`: joining and welding the parts of a loaded scene;
- :mod:`~geoscaler.io.images`: image decoding (:func:`image_to_texture`) and the one image
  encoder (:func:`encoded_image`: the input's bytes where a texture is unchanged);
- :mod:`~geoscaler.io.paths`: path safety, for reading (references stay inside the mesh's
  folder) and writing (:func:`check_outputs`, the one output check; :func:`prepare_folder`);
- :mod:`~geoscaler.io.discover`: the assets of a folder tree (:func:`find_assets`);
- :mod:`~geoscaler.io.atomic`: atomic writes (:func:`write_atomically`, :func:`save_png`).

Only the names below are public; the modules' other names are internal to this package.
"""

from .atomic import save_png, write_atomically
from .discover import FoundAsset, find_assets, meta_entry
from .images import IMAGE_FORMATS, JPEG_QUALITY, encoded_image, image_to_texture
from .load import load_mesh
from .paths import SUPPORTED_SUFFIXES, check_output, check_outputs, prepare_folder
from .save import output_files, save_mesh, written_image

__all__ = [
    "FoundAsset",
    "find_assets",
    "meta_entry",
    "IMAGE_FORMATS",
    "JPEG_QUALITY",
    "SUPPORTED_SUFFIXES",
    "check_output",
    "check_outputs",
    "encoded_image",
    "image_to_texture",
    "load_mesh",
    "output_files",
    "prepare_folder",
    "save_mesh",
    "written_image",
    "save_png",
    "write_atomically",
]
