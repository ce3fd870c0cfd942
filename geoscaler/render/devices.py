"""Which torch device a run uses (CUDA when torch sees a GPU, unless told otherwise), a mesh's
arrays on it as every renderer starts from them, and what tensors hold there."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import torch

from geoscaler.errors import GeoscalerError

if TYPE_CHECKING:
    from geoscaler.mesh import TexturedMesh


def resolve_device(name: str | torch.device | None = None) -> torch.device:
    """The torch device for ``name``: ``None``/``"auto"`` means CUDA when torch sees a GPU."""
    if name is None or name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise GeoscalerError("device cuda: torch sees no CUDA GPU here; use --device cpu or auto")
    return device


class MeshTensors(NamedTuple):
    """A mesh's arrays as the renderers hold them, on one torch device."""

    positions: torch.Tensor  # (V, 3) float32, the protocol's unit scene
    faces: torch.Tensor  # (F, 3) int64
    uvs: torch.Tensor  # (V, 2) float32
    face_material: torch.Tensor  # (F,) int64
    factors: torch.Tensor  # (M, 3) float32 linear base-colour factors


def mesh_tensors(mesh: TexturedMesh, device: torch.device) -> MeshTensors:
    """The tensors every renderer of ``mesh`` starts from, on ``device``."""
    factors = np.stack([m.base_color_factor[:3] for m in mesh.materials]).astype(np.float32)
    arrays = (
        mesh.normalized_positions(),
        np.asarray(mesh.faces, dtype=np.int64),
        np.asarray(mesh.uvs, dtype=np.float32),
        np.asarray(mesh.face_material, dtype=np.int64),
        factors,
    )
    return MeshTensors(*(torch.from_numpy(a).to(device) for a in arrays))


def tensor_bytes(tensors: Iterable[torch.Tensor]) -> int:
    """Bytes of the elements of ``tensors`` (views of one storage counted each)."""
    return sum(t.element_size() * t.nelement() for t in tensors)
