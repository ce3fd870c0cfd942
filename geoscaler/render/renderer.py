"""Images of a textured mesh from cached G-buffers, exactly as PROTOCOL.md defines them.

The pipeline is deferred: :meth:`Renderer.rasterize` runs once per camera (visibility is fixed),
then :meth:`Renderer.shade` interpolates UVs, takes their screen derivatives and filters the
texture for every covered sample, and :meth:`Renderer.resolve` box-averages the 2 x 2 samples of
each pixel. Shading and resolving are differentiable with respect to texels and UVs.

Colours are linear light until :func:`geoscaler.color.linear_to_srgb` encodes the final image.
The background is black. Pixel colour = base-colour texture sample x base-colour factor (unlit).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import numpy as np
import torch

from geoscaler.color import linear_to_srgb, texture_to_linear
from geoscaler.mesh import TexturedMesh
from geoscaler.protocol import PROTOCOL_EVALUATION, Evaluation
from geoscaler.render.cameras import Camera
from geoscaler.render.devices import mesh_tensors, resolve_device
from geoscaler.render.encoded import EncodedMipTexture
from geoscaler.render.raster import GBuffer, rasterize
from geoscaler.render.texture import MipTexture, UVFootprint
from geoscaler.resize.filters import reference_textures


class Renderer:
    """Renders one mesh, normalised per the protocol, from protocol cameras.

    Args:
        mesh: the mesh; its geometry is fixed for the renderer's lifetime.
        device: where tensors live (None or "auto": CUDA when available).
        evaluation: image size and supersampling (default: protocol 1's).
    """

    def __init__(
        self,
        mesh: TexturedMesh,
        device: torch.device | str | None = None,
        evaluation: Evaluation = PROTOCOL_EVALUATION,
    ):
        self.device = resolve_device(device)
        self.evaluation = evaluation
        self.image_size = evaluation.image_size
        self.supersample = evaluation.supersample
        self.mesh = mesh
        tensors = mesh_tensors(mesh, self.device)
        self.positions, self.faces, self.uvs = tensors.positions, tensors.faces, tensors.uvs
        self.face_material, self.factors = tensors.face_material, tensors.factors
        self._reference: list[MipTexture | None] | None = None
        self._reference_maps: list[np.ndarray | None] | None = None
        self.original = mesh
        self.reference_uvs: torch.Tensor | None = None
        self.view_memo: dict | None = None

    def relaid(self, uvs: np.ndarray, memo: dict | None = None) -> Renderer:
        """A renderer of the same mesh in a new UV layout: ``(V, 2)`` new UVs of the same
        vertices or ``(F, 3, 2)`` of every face corner (3D positions and faces unchanged, so
        every G-buffer is the same; its :attr:`mesh` is :meth:`TexturedMesh.with_uvs`'s).
        Candidates are rendered with the new UVs, references as before: the original maps on
        the original UVs. ``memo`` (a dict, shared with other renderers of the mesh) keeps each
        camera's G-buffer and reference so a view is rasterised once (:meth:`cached_view`).
        """
        relaid = copy.copy(self)
        relaid.mesh = self.original.with_uvs(uvs)
        relaid.uvs = torch.as_tensor(np.asarray(uvs, np.float32), device=self.device)
        relaid.reference_uvs = self.uvs if self.reference_uvs is None else self.reference_uvs
        relaid.view_memo = memo
        return relaid

    def render_reference(self, gbuffer: GBuffer) -> torch.Tensor:
        """``(image_size, image_size, 3)`` sRGB image of the original: its reference maps on
        its own UVs, whatever this renderer's layout."""
        return self.render(gbuffer, self.reference_textures(), self.reference_uvs)

    def cached_view(self, camera: Camera) -> tuple[GBuffer, torch.Tensor, torch.Tensor]:
        """``(G-buffer, reference image, (H, W) foreground)`` of a camera, from
        :attr:`view_memo` when it holds them (and kept there when there is a memo)."""
        key = (camera.direction, camera.distance)
        if self.view_memo is not None and key in self.view_memo:
            return self.view_memo[key]
        gbuffer = self.rasterize(camera)
        view = gbuffer, self.render_reference(gbuffer), self.foreground(gbuffer)
        if self.view_memo is not None:
            self.view_memo[key] = view
        return view

    @property
    def resolution(self) -> int:
        """Samples per side of the G-buffer."""
        return self.image_size * self.supersample

    def mip_textures(self, textures: Sequence[np.ndarray | None]) -> list[MipTexture | None]:
        """Mip chains on this renderer's device of ``(h, w, C)`` uint8 sRGB textures, one per
        material (None: untextured)."""
        return [
            None if texture is None else MipTexture(texture_to_linear(texture, self.device))
            for texture in textures
        ]

    def reference_maps(self) -> list[np.ndarray | None]:
        """Per material the ``(H, W, C)`` uint8 map views of the original are rendered from:
        the original, reduced to the evaluation's ``reference_max_size`` where it is longer
        (:func:`geoscaler.resize.filters.reference_textures`; None for untextured materials), made
        once per renderer (read only)."""
        if self._reference_maps is None:
            maximum = self.evaluation.reference_max_size
            self._reference_maps = reference_textures(self.original, maximum)
        return list(self._reference_maps)

    def reference_textures(self) -> list[MipTexture | None]:
        """Mip chains of :meth:`reference_maps`, made once per renderer (read only), one per
        distinct map (materials showing one image share it): :class:`~geoscaler.render.texture.
        EncodedMipTexture`, whose level 0 is the map's own 8-bit texels, so that a large
        original is never held in float32 at full size."""
        if self._reference is None:
            chains: dict[int, MipTexture] = {}
            for texture in self.reference_maps():
                if texture is not None and id(texture) not in chains:
                    chains[id(texture)] = EncodedMipTexture(texture, self.device)
            self._reference = [
                None if texture is None else chains[id(texture)]
                for texture in self.reference_maps()
            ]
        return self._reference

    def rasterize(self, camera: Camera, resolution: int | None = None) -> GBuffer:
        """The G-buffer of one camera at ``resolution`` samples per side (default:
        :attr:`resolution`)."""
        clip_matrix = torch.from_numpy(camera.clip_matrix()).to(self.device, torch.float64)
        homogeneous = torch.nn.functional.pad(self.positions.to(torch.float64), (0, 1), value=1.0)
        return rasterize(homogeneous @ clip_matrix.T, self.faces, resolution or self.resolution)

    def footprint(self, gbuffer: GBuffer, uvs: torch.Tensor | None = None) -> UVFootprint:
        """Interpolated UVs and their screen derivatives at every covered sample.

        Args:
            gbuffer: visibility from :meth:`rasterize`.
            uvs: UVs to use instead of the renderer's own: ``(V, 2)`` per vertex (e.g. warped
                ones) or ``(F, 3, 2)`` per face corner (a layout that cut charts).
        """
        uvs = self.uvs if uvs is None else uvs
        if uvs.dim() == 2:
            uvs = uvs.index_select(0, self.faces.view(-1)).view(-1, 3, 2)
        corner_uvs = uvs.permute(2, 0, 1)
        (u, v), (du_dx, dv_dx), (du_dy, dv_dy) = gbuffer.interpolate(corner_uvs)
        return UVFootprint(u, v, du_dx, dv_dx, du_dy, dv_dy)

    def shade(
        self,
        gbuffer: GBuffer,
        textures: Sequence[MipTexture | None],
        uvs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Linear colour of every covered sample.

        Args:
            gbuffer: visibility from :meth:`rasterize`.
            textures: one mip chain per material (None: the factor alone is the colour).
            uvs: UVs to use instead of the renderer's own (:meth:`footprint`).

        Returns:
            ``(3, N)`` float32 linear RGB, in the order of ``gbuffer.pixels``.
        """
        footprint = self.footprint(gbuffer, uvs)
        if len(textures) == 1:
            colour = self.factors[0][:, None]
            if textures[0] is None:
                return colour.expand(3, footprint.u.shape[0])
            return colour * textures[0].sample(footprint)
        material = self.face_material.index_select(0, gbuffer.tri_ids)
        colours = self.factors.T.index_select(1, material)
        for index, texture in enumerate(textures):
            hit = torch.nonzero(material == index).squeeze(1)
            if texture is not None and len(hit):
                texel = texture.sample(UVFootprint(*(t.index_select(0, hit) for t in footprint)))
                colours = colours.index_copy(1, hit, colours[:, hit] * texel)
        return colours

    def resolve(self, gbuffer: GBuffer, colours: torch.Tensor) -> torch.Tensor:
        """Box-average the samples of each pixel (background black).

        Args:
            colours: ``(C, N)`` per-sample values in ``gbuffer.pixels`` order.

        Returns:
            ``(image_size, image_size, C)`` image.
        """
        pixel = self.pixel_of_sample(gbuffer)
        share = 1.0 / self.supersample**2
        image = torch.stack(
            [row.new_zeros(self.image_size**2).index_add(0, pixel, row) for row in colours]
        )
        side = self.image_size
        return (image * share).view(-1, side, side).permute(1, 2, 0)

    def pixel_of_sample(self, gbuffer: GBuffer) -> torch.Tensor:
        """``(N,)`` int32 flat index of the output pixel each covered sample belongs to."""
        samples = gbuffer.pixels.int()
        row = samples // (self.resolution * self.supersample)
        col = samples % self.resolution // self.supersample
        return row * self.image_size + col

    def foreground(self, gbuffer: GBuffer) -> torch.Tensor:
        """``(image_size, image_size)`` bool: pixels with any covered sample."""
        mask = torch.zeros(self.image_size**2, dtype=torch.bool, device=self.device)
        mask[self.pixel_of_sample(gbuffer)] = True
        return mask.view(self.image_size, self.image_size)

    def render(
        self,
        gbuffer: GBuffer,
        textures: Sequence[MipTexture | None],
        uvs: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``(image_size, image_size, 3)`` sRGB-encoded image in [0, 1]."""
        return linear_to_srgb(self.resolve(gbuffer, self.shade(gbuffer, textures, uvs)))


def image_to_uint8(image: torch.Tensor) -> np.ndarray:
    """``(H, W, C)`` sRGB float image in [0, 1] to uint8 for saving."""
    return image.detach().clamp(0, 1).mul(255).round().to(torch.uint8).cpu().numpy()
