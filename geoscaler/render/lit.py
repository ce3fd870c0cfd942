"""Protocol 2 of PROTOCOL.md: every map of a PBR material through lit renders.

A lit render reuses protocol 1's pipeline (one G-buffer per camera, the one sampler, 2 x 2
samples box-averaged, sRGB encoding) and replaces the unlit colour of each sample by the
radiance of the glTF metallic-roughness BRDF (the specification's Appendix B) under two
camera-relative directional lights and a uniform ambient:

- :func:`shade`: the BRDF and the lights, per sample, from :class:`Surface` inputs;
- :func:`shading_normal`: the tangent frame of each sample and its normal-map normal;
- :func:`vertex_tangents`: tangents where a mesh stores none (Lengyel's sums, as the protocol
  words them);
- :class:`LitMaterial`: one material's maps as mip chains with its factors;
- :class:`LitScene`: a mesh's geometry for lit views; :meth:`LitScene.view` caches what a
  camera's samples need whatever the maps (frame, view vectors, UV footprints),
  :meth:`LitScene.render` shades maps on it.

Shading is differentiable in every map's texels (and in the UVs of a footprint that carries
gradients). Vectors are ``(3, N)``: one contiguous row per component, as the sampler returns
them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from geoscaler.color import linear_to_srgb
from geoscaler.errors import GeoscalerError
from geoscaler.io.slots import slot_info
from geoscaler.mesh import BASE_COLOR, Material, TexturedMesh
from geoscaler.protocol import (
    AMBIENT_RADIANCE,
    FILL_LIGHT,
    KEY_LIGHT,
    MIN_PERCEPTUAL_ROUGHNESS,
    Evaluation,
)
from geoscaler.render.cameras import Camera
from geoscaler.render.encoded import Decoding, EncodedMipTexture, srgb_decoding
from geoscaler.render.metrics import evaluate
from geoscaler.render.raster import GBuffer
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture, UVFootprint

DIELECTRIC_F0 = 0.04
"""Reflectance at normal incidence of every dielectric (glTF's metallic-roughness model)."""
MIN_NV = 1e-4
"""Smallest ``n . v`` the BRDF divides by (the protocol's clamp)."""

_LINEAR = np.arange(256, dtype=np.float32) / np.float32(255.0)
"""``(256,)`` float32: an 8-bit code read as a linear value in [0, 1] (data and normal maps)."""


@dataclass(frozen=True)
class Light:
    """A directional light: ``direction`` ``(3,)`` unit vector from the surface towards the
    light, in the scene's frame; ``irradiance`` on a surface facing it (white)."""

    direction: tuple[float, float, float]
    irradiance: float


def camera_lights(camera: Camera) -> list[Light]:
    """The key and fill lights of a camera (PROTOCOL.md: camera-relative, so every view is lit
    alike): ``normalize(d + up_share c_up + right_share c_right)`` each."""
    right, up, back = camera.axes()
    lights = []
    for up_share, right_share, irradiance in (KEY_LIGHT, FILL_LIGHT):
        direction = back + up_share * up + right_share * right
        direction /= np.linalg.norm(direction)
        lights.append(Light(tuple(float(x) for x in direction), irradiance))
    return lights


@dataclass
class Surface:
    """The material inputs of N samples, linear light.

    Attributes:
        base_color: ``(3, N)`` ``C``, base colour times its factor.
        metallic: ``(N,)`` ``m`` in [0, 1].
        roughness: ``(N,)`` perceptual roughness ``r`` (clamped in :func:`shade`).
        occlusion: ``(N,)`` ``o`` in [0, 1].
        emissive: ``(3, N)`` emitted radiance ``Le``.
        normal: ``(3, N)`` unit shading normal ``n``.
    """

    base_color: torch.Tensor
    metallic: torch.Tensor
    roughness: torch.Tensor
    occlusion: torch.Tensor
    emissive: torch.Tensor
    normal: torch.Tensor


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``(N,)`` dot products of ``(3, N)`` vectors (``b`` may be ``(3, 1)``)."""
    return (a * b).sum(0)


def _unit(vectors: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """``(3, N)`` vectors scaled to unit length (zero ones stay zero). The length is summed
    row by row: ``Tensor.norm`` over the first dimension is about 10 times slower on the
    CPU."""
    length = torch.sqrt(_dot(vectors, vectors)).clamp_min(eps)
    return vectors / length


def shade(surface: Surface, view: torch.Tensor, lights: Sequence[Light]) -> torch.Tensor:
    """``(3, N)`` radiance of every sample, clamped to [0, 1] (PROTOCOL.md, protocol 2).

    ``L = sum_i E_i f(l_i) (n . l_i)+ + A o (c_diff + F0) + Le`` with the glTF BRDF
    ``f = (1 - F) c_diff / pi + F D Vis`` (Schlick's Fresnel, the GGX distribution, the
    height-correlated Smith visibility), ``a = r^2``.

    Args:
        surface: the material inputs of the samples.
        view: ``(3, N)`` unit vectors from each sample towards the eye.
        lights: directional lights (:func:`camera_lights`).
    """
    metallic = surface.metallic
    c_diff = surface.base_color * (1 - metallic)
    f0 = DIELECTRIC_F0 * (1 - metallic) + surface.base_color * metallic
    alpha = surface.roughness.clamp(MIN_PERCEPTUAL_ROUGHNESS, 1.0) ** 2
    alpha_sq = alpha * alpha
    n = surface.normal
    nv = _dot(n, view).clamp_min(MIN_NV)
    radiance = AMBIENT_RADIANCE * surface.occlusion * (c_diff + f0) + surface.emissive
    for light in lights:
        l_dir = torch.tensor(light.direction, dtype=n.dtype, device=n.device)[:, None]
        half = _unit(l_dir + view)
        nl = _dot(n, l_dir).clamp_min(0.0)
        nh = _dot(n, half).clamp_min(0.0)
        vh = _dot(view, half).clamp_min(0.0)
        fresnel = f0 + (1 - f0) * (1 - vh) ** 5
        distribution = alpha_sq / (math.pi * (nh * nh * (alpha_sq - 1) + 1) ** 2)
        visibility = 0.5 / (
            nl * torch.sqrt(nv * nv * (1 - alpha_sq) + alpha_sq)
            + nv * torch.sqrt(nl * nl * (1 - alpha_sq) + alpha_sq)
        )
        brdf = (1 - fresnel) * c_diff / math.pi + fresnel * (distribution * visibility)
        radiance = radiance + light.irradiance * brdf * nl
    return radiance.clamp(0.0, 1.0)


def shading_normal(
    geometric: torch.Tensor,
    tangent: torch.Tensor,
    handedness: torch.Tensor,
    view: torch.Tensor,
    texel: torch.Tensor | None = None,
    scale: torch.Tensor | float = 1.0,
) -> torch.Tensor:
    """``(3, N)`` unit shading normals: the normal map's vector in each sample's frame
    (:func:`shading_frame`, then :func:`framed_normal`).

    Args:
        geometric: ``(3, N)`` interpolated vertex normals.
        tangent: ``(3, N)`` interpolated tangents.
        handedness: ``(N,)`` interpolated tangent ``w`` (its sign is used).
        view: ``(3, N)`` unit vectors towards the eye.
        texel: ``(3, N)`` the normal map's linear values in [0, 1], or None (no map).
        scale: ``normalTexture.scale``, a number or ``(N,)``.
    """
    return framed_normal(shading_frame(geometric, tangent, handedness, view), texel, scale)


def shading_frame(
    geometric: torch.Tensor, tangent: torch.Tensor, handedness: torch.Tensor, view: torch.Tensor
) -> torch.Tensor:
    """``(3, 3, N)`` the tangent frame ``(T, B, N)`` of every sample, facing the eye.

    PROTOCOL.md: ``Ng`` normalised, ``T`` made orthogonal to it, ``B = h (Ng x T)``; where the
    back of the surface is seen (``Ng . v < 0``) the whole frame is negated.

    Args: as :func:`shading_normal`'s.
    """
    normal = _unit(geometric)
    facing = torch.where(_dot(normal, view) < 0, -1.0, 1.0).to(normal.dtype)
    tangent = _unit(tangent - normal * _dot(normal, tangent))
    sign = torch.where(handedness < 0, -1.0, 1.0).to(normal.dtype)
    bitangent = torch.linalg.cross(normal, tangent, dim=0) * sign
    return torch.stack([tangent, bitangent, normal]) * facing


def framed_normal(
    frame: torch.Tensor, texel: torch.Tensor | None, scale: torch.Tensor | float = 1.0
) -> torch.Tensor:
    """``(3, N)`` unit shading normals in a ``(3, 3, N)`` :func:`shading_frame`: ``N`` without
    a map; with one, ``t = 2 c - 1``, ``t.xy *= scale``, ``n = normalize(t.x T + t.y B +
    t.z N)`` (OpenGL-style green: ``+y`` along ``B``, towards increasing ``v``).

    Args:
        frame: ``(3, 3, N)`` ``(T, B, N)``.
        texel: ``(3, N)`` the normal map's linear values in [0, 1], or None (no map).
        scale: ``normalTexture.scale``, a number or ``(N,)``.
    """
    if texel is None:
        return frame[2]
    vector = 2 * texel - 1
    return _unit(vector[0] * scale * frame[0] + vector[1] * scale * frame[1] + vector[2] * frame[2])


def vertex_tangents(
    positions: np.ndarray, faces: np.ndarray, uvs: np.ndarray, normals: np.ndarray
) -> np.ndarray:
    """``(V, 4)`` float32 tangents (unit xyz, handedness ``w = +-1``) from a UV set.

    Per triangle ``dp/du = (e1 dv2 - e2 dv1) / (du1 dv2 - du2 dv1)`` and ``dp/dv`` likewise
    (Lengyel), not normalised (larger triangles weigh more), summed over each vertex's
    triangles; ``T`` = the sum normalised, ``w = +1`` where ``(N x T) . dp/dv > 0`` (UVs in
    the OpenGL convention: the bitangent points up the texture). Triangles without UV area
    add nothing; a vertex with no tangent gets ``(1, 0, 0, 1)``.

    Args:
        positions: ``(V, 3)`` vertex positions.
        faces: ``(F, 3)`` vertex indices.
        uvs: ``(V, 2)`` texture coordinates (OpenGL convention).
        normals: ``(V, 3)`` unit vertex normals.
    """
    corners = np.asarray(positions, np.float64)[faces]
    corner_uvs = np.asarray(uvs, np.float64)[faces]
    e1, e2 = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    du1, dv1 = (corner_uvs[:, 1] - corner_uvs[:, 0]).T
    du2, dv2 = (corner_uvs[:, 2] - corner_uvs[:, 0]).T
    det = du1 * dv2 - du2 * dv1
    inverse = np.divide(1.0, det, out=np.zeros_like(det), where=np.abs(det) > 1e-20)
    dp_du = (e1 * dv2[:, None] - e2 * dv1[:, None]) * inverse[:, None]
    dp_dv = (e2 * du1[:, None] - e1 * du2[:, None]) * inverse[:, None]
    count = len(positions)
    sums = []
    for per_face in (dp_du, dp_dv):
        weights = np.repeat(per_face, 3, axis=0)
        sums.append(
            np.stack(
                [np.bincount(faces.ravel(), weights[:, k], minlength=count) for k in range(3)], 1
            )
        )
    length = np.linalg.norm(sums[0], axis=1, keepdims=True)
    tangent = np.where(length > 1e-20, sums[0] / np.maximum(length, 1e-20), [1.0, 0.0, 0.0])
    up = np.einsum("ij,ij->i", np.cross(normals, tangent), sums[1])
    handedness = np.where(up < 0, -1.0, 1.0)
    return np.concatenate([tangent, handedness[:, None]], axis=1).astype(np.float32)


METALLIC_ROUGHNESS = "metallicRoughnessTexture"
NORMAL = "normalTexture"
OCCLUSION = "occlusionTexture"
EMISSIVE = "emissiveTexture"
LIT_SLOTS = (BASE_COLOR, METALLIC_ROUGHNESS, NORMAL, OCCLUSION, EMISSIVE)
"""The maps protocol 2 reads; every other slot of a material is ignored by the lit render."""
SRGB_SLOTS = (BASE_COLOR, EMISSIVE)
"""The lit slots whose texels are sRGB-encoded colour; the others hold linear values."""


def map_decoding(slot: str, channels: int) -> Decoding:
    """How a slot's 8-bit texels become the three values the lit render reads: linear RGB of
    sRGB colour maps, the codes / 255 of data and normal maps (a grey map's one channel
    repeated; alpha never read)."""
    if slot in SRGB_SLOTS:
        return srgb_decoding(channels)
    return [(c if channels >= 3 else 0, _LINEAR) for c in range(3)]


def decoded_map(pixels: np.ndarray, slot: str, device: torch.device | str) -> torch.Tensor:
    """``(H, W, 3)`` float32 values of an 8-bit map of ``slot`` as the lit render reads them
    (:func:`map_decoding`): what a differentiable candidate starts from."""
    codes = torch.from_numpy(np.asarray(pixels, dtype=np.int64)).to(device)
    codes = codes if codes.dim() == 3 else codes[..., None]
    planes = [
        torch.from_numpy(table).to(device)[codes[..., source]]
        for source, table in map_decoding(slot, codes.shape[2])
    ]
    return torch.stack(planes, dim=-1)


@dataclass
class LitMaterial:
    """One material as protocol 2 renders it: each map a mip chain of three linear values per
    texel (:func:`decoded_map`; None: the material has no such map) and the factors.

    Attributes:
        maps: slot (:data:`LIT_SLOTS`) -> chain; a slot absent or None has no map.
        base_color_factor: ``(3,)`` linear RGB.
        metallic_factor, roughness_factor: glTF's, defaults 1.
        normal_scale: ``normalTexture.scale``; occlusion_strength: ``occlusionTexture.strength``.
        emissive: ``(3,)`` emissive factor times ``KHR_materials_emissive_strength``.
    """

    maps: dict[str, MipTexture | None]
    base_color_factor: tuple[float, float, float]
    metallic_factor: float = 1.0
    roughness_factor: float = 1.0
    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    emissive: tuple[float, float, float] = (0.0, 0.0, 0.0)


def lit_factors(material: Material) -> dict:
    """The protocol's factors of a material (an MTL material: metallic 0, roughness 1)."""
    properties = material.properties
    pbr = properties.get("pbrMetallicRoughness", {})
    from_mtl = "mtl" in properties
    strength = properties.get("extensions", {}).get("KHR_materials_emissive_strength", {})
    emissive = np.asarray(properties.get("emissiveFactor", (0.0, 0.0, 0.0)), np.float64)
    emissive = emissive * float(strength.get("emissiveStrength", 1.0))
    return {
        "base_color_factor": tuple(float(x) for x in material.base_color_factor[:3]),
        "metallic_factor": 0.0 if from_mtl else float(pbr.get("metallicFactor", 1.0)),
        "roughness_factor": 1.0 if from_mtl else float(pbr.get("roughnessFactor", 1.0)),
        "normal_scale": float(slot_info(properties, NORMAL).get("scale", 1.0)),
        "occlusion_strength": float(slot_info(properties, OCCLUSION).get("strength", 1.0)),
        "emissive": tuple(float(x) for x in emissive),
    }


def lit_maps(material: Material) -> dict[str, np.ndarray]:
    """The material's maps protocol 2 reads, by slot; refused where one is not on the UV set
    the mesh's UVs hold (another ``texCoord``, or a texture transform the base colour has not)."""
    maps = {slot: pixels for slot, pixels in material.textures().items() if slot in LIT_SLOTS}
    if "mtl" in material.properties:
        maps.pop(NORMAL, None)  # protocol 2: OBJ materials have no normal map
    base_transform = _transform(material, BASE_COLOR)
    for slot in maps:
        info = slot_info(material.properties, slot)
        if info.get("texCoord", 0) != 0 or _transform(material, slot) != base_transform:
            raise GeoscalerError(
                f"material {material.name!r}: its {slot} is on another UV set or has its own "
                "texture transform; lit (protocol 2) renders read every map on the base "
                "colour's UVs only: score it under protocol 1 (--protocol 1)"
            )
    return maps


def _transform(material: Material, slot: str) -> dict | None:
    extensions = slot_info(material.properties, slot).get("extensions", {})
    return extensions.get("KHR_texture_transform") if isinstance(extensions, dict) else None


def lit_materials(
    mesh: TexturedMesh, device: torch.device | str, encoded: bool = True
) -> list[LitMaterial]:
    """Every material of ``mesh`` ready for :meth:`LitScene.render`, one chain per distinct
    map (shared images stay shared). ``encoded``: chains that keep level 0 as 8-bit codes
    (:class:`~geoscaler.render.encoded.EncodedMipTexture`: references, scoring); otherwise
    float chains (:class:`~geoscaler.render.texture.MipTexture`) of :func:`decoded_map`.
    """
    chains: dict[tuple[int, str], MipTexture] = {}
    materials = []
    for material in mesh.materials:
        maps: dict[str, MipTexture | None] = {}
        for slot, pixels in lit_maps(material).items():
            key = (id(pixels), "srgb" if slot in SRGB_SLOTS else "linear")
            if key not in chains:
                channels = 1 if pixels.ndim == 2 else pixels.shape[2]
                chains[key] = (
                    EncodedMipTexture(pixels, device, map_decoding(slot, channels))
                    if encoded
                    else MipTexture(decoded_map(pixels, slot, device))
                )
            maps[slot] = chains[key]
        materials.append(LitMaterial(maps, **lit_factors(material)))
    return materials


@dataclass
class LitView:
    """What one camera's covered samples need for lit shading, whatever the maps.

    Attributes:
        gbuffer: the camera's visibility.
        footprint: UVs and their derivatives per sample.
        view: ``(3, N)`` unit vectors from each sample to the eye.
        geometric, tangent: ``(3, N)`` interpolated vertex normals and tangents.
        handedness: ``(N,)`` interpolated tangent ``w``.
        material: ``(N,)`` material index of each sample.
        lights: the camera's lights.
    """

    gbuffer: GBuffer
    footprint: UVFootprint
    view: torch.Tensor
    geometric: torch.Tensor
    tangent: torch.Tensor
    handedness: torch.Tensor
    material: torch.Tensor
    lights: list[Light]


class LitScene:
    """A mesh's geometry for lit renders (PROTOCOL.md, protocol 2).

    Args:
        renderer: the mesh's renderer (its normalised positions, faces, UVs, G-buffers).
    """

    def __init__(self, renderer: Renderer):
        self.renderer = renderer
        mesh = renderer.mesh
        tangents = mesh.attributes.get("TANGENT")
        if tangents is None:
            tangents = vertex_tangents(mesh.positions, mesh.faces, mesh.uvs, mesh.normals)
        device = renderer.device
        per_vertex = torch.cat(
            [
                renderer.positions,
                torch.from_numpy(np.asarray(mesh.normals, np.float32)).to(device),
                torch.from_numpy(np.asarray(tangents, np.float32)).to(device),
            ],
            dim=1,
        )  # (V, 10)
        self._corners = per_vertex[renderer.faces].permute(2, 0, 1).contiguous()  # (10, F, 3)

    def view(self, camera: Camera, gbuffer: GBuffer | None = None) -> LitView:
        """The lit inputs of ``camera``'s samples (its G-buffer rasterised unless given)."""
        renderer = self.renderer
        gbuffer = renderer.rasterize(camera) if gbuffer is None else gbuffer
        values = gbuffer.interpolate(self._corners)[0]  # (10, N)
        eye = torch.tensor(camera.eye, dtype=values.dtype, device=values.device)[:, None]
        return LitView(
            gbuffer,
            renderer.footprint(gbuffer),
            _unit(eye - values[0:3]),
            values[3:6],
            values[6:9],
            values[9],
            renderer.face_material.index_select(0, gbuffer.tri_ids),
            camera_lights(camera),
        )

    def render(self, view: LitView, materials: Sequence[LitMaterial]) -> torch.Tensor:
        """``(image_size, image_size, 3)`` sRGB lit image of ``materials`` (one per material of
        the mesh) in ``view``; differentiable in the float chains' texels."""
        radiance = shade(self.surface(view, materials), view.view, view.lights)
        return linear_to_srgb(self.renderer.resolve(view.gbuffer, radiance))

    def surface(self, view: LitView, materials: Sequence[LitMaterial]) -> Surface:
        """The :class:`Surface` of every sample of ``view``, each material's maps sampled
        where it is seen."""
        if len(materials) == 1:
            return _material_surface(view, materials[0], None)
        hits = [torch.nonzero(view.material == i).squeeze(1) for i in range(len(materials))]
        parts = [_material_surface(view, m, hit) for m, hit in zip(materials, hits, strict=True)]
        order = torch.cat(hits)
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(len(order), device=order.device)
        fields = [torch.cat([getattr(p, f) for p in parts], -1) for f in _SURFACE_FIELDS]
        return Surface(*(f.index_select(-1, inverse) for f in fields))


_SURFACE_FIELDS = ("base_color", "metallic", "roughness", "occlusion", "emissive", "normal")


def _material_surface(view: LitView, material: LitMaterial, hit: torch.Tensor | None) -> Surface:
    """The :class:`Surface` of the samples ``hit`` (all when None) of one material."""

    def pick(t: torch.Tensor) -> torch.Tensor:
        return t if hit is None else t.index_select(-1, hit)

    footprint = UVFootprint(*(pick(t) for t in view.footprint))
    geometry = (view.geometric, view.tangent, view.handedness, view.view)
    frame = shading_frame(*(pick(t) for t in geometry))

    def sampled(slot: str) -> torch.Tensor | None:
        chain = material.maps.get(slot)
        return None if chain is None else chain.sample(footprint)

    return material_surface(material, frame, sampled)


def material_surface(
    material: LitMaterial, frame: torch.Tensor, sampled: Callable[[str], torch.Tensor | None]
) -> Surface:
    """The :class:`Surface` of N samples of one material.

    Args:
        material: the material's factors (and which maps it has).
        frame: ``(3, 3, N)`` the samples' :func:`shading_frame`.
        sampled: slot -> ``(3, N)`` the slot's map read at the samples (None: no map).
    """
    ones = frame.new_ones(frame.shape[2])

    def constant(values: Sequence[float]) -> torch.Tensor:
        return torch.tensor(values, dtype=ones.dtype, device=ones.device)[:, None] * ones

    base = constant(material.base_color_factor)
    if (texel := sampled(BASE_COLOR)) is not None:
        base = base * texel
    metallic, roughness = material.metallic_factor * ones, material.roughness_factor * ones
    if (texel := sampled(METALLIC_ROUGHNESS)) is not None:
        metallic, roughness = texel[2] * metallic, texel[1] * roughness
    occlusion = ones
    if (texel := sampled(OCCLUSION)) is not None:
        occlusion = 1 + material.occlusion_strength * (texel[0] - 1)
    emissive = constant(material.emissive)
    if (texel := sampled(EMISSIVE)) is not None:
        emissive = emissive * texel
    normal = framed_normal(frame, sampled(NORMAL), material.normal_scale)
    return Surface(base, metallic, roughness, occlusion, emissive, normal)


def default_protocol(mesh: TexturedMesh) -> int:
    """The protocol a mesh is scored under unless asked: 2 (lit) where a glTF material has a
    normal or metallic-roughness map, whose detail only light shows, and every material's
    maps are on the UVs lit renders read (:func:`lit_maps`); 1 (unlit base colour) otherwise
    (OBJ materials have neither map under protocol 2)."""
    lit = any(
        NORMAL in m.maps or METALLIC_ROUGHNESS in m.maps
        for m in mesh.materials
        if "mtl" not in m.properties
    )
    try:
        for material in mesh.materials:
            lit_maps(material)
    except GeoscalerError:
        return 1
    return 2 if lit else 1


def lit_scores(
    original: TexturedMesh,
    candidates: Sequence[TexturedMesh],
    cameras: Sequence[Camera],
    device: torch.device | str | None = None,
    evaluation: Evaluation | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> tuple[list[dict[str, torch.Tensor]], np.ndarray]:
    """Protocol 2 metrics of every candidate against the original, per camera.

    References are the original's maps at full resolution (``evaluation``'s image size and
    supersampling, default protocol 1's, its reference cap ignored). A candidate whose
    positions, faces and UVs are the original's very arrays (maps replaced only) is rendered
    on the original's G-buffers and frames; any other is rasterised on its own.

    Returns:
        Per candidate ``{"psnr_fg", "psnr_full", "ssim_full", "ssim_fg"}`` -> ``(len(cameras),)``,
        and ``(len(cameras),)`` int64 foreground pixels of each view.
    """
    evaluation = replace(evaluation or Evaluation(), reference_max_size=None)
    renderer = Renderer(original, device, evaluation)
    scene = LitScene(renderer)
    reference = lit_materials(original, renderer.device)
    scenes = [
        scene if _same_geometry(original, c) else LitScene(Renderer(c, device, evaluation))
        for c in candidates
    ]
    materials = [lit_materials(c, renderer.device) for c in candidates]
    per_view: list[list[dict[str, torch.Tensor]]] = [[] for _ in candidates]
    foreground_pixels = []
    with torch.no_grad():
        for index, camera in enumerate(cameras):
            view = scene.view(camera)
            reference_image = scene.render(view, reference)[None]
            foreground = renderer.foreground(view.gbuffer)[None]
            foreground_pixels.append(int(foreground.sum()))
            for k, (own, maps) in enumerate(zip(scenes, materials, strict=True)):
                own_view = view if own is scene else own.view(camera)
                image = own.render(own_view, maps)[None]
                per_view[k].append(evaluate(image, reference_image, foreground))
            if progress:
                progress(index + 1, len(cameras))
    scores = [{m: torch.cat([v[m] for v in views]) for m in views[0]} for views in per_view]
    return scores, np.asarray(foreground_pixels, np.int64)


def _same_geometry(original: TexturedMesh, candidate: TexturedMesh) -> bool:
    return all(
        getattr(candidate, name) is getattr(original, name)
        for name in ("positions", "faces", "uvs", "normals")
    )
