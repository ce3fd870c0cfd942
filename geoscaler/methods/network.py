"""Method ``geoscaler``: the paper's network, trained per mesh through the protocol renderer.

The network maps the texture and its geometry maps to the small texture (and, for the
warping variants, new UVs); its weights are the parameters of the shared optimisation loop
(:func:`geoscaler.optim.loop.optimize`), exactly as the texels are for ``direct``. Registered
as ``geoscaler`` and, one per ablation variant, ``geoscaler-base``, ``-gcm``, ``-uvw``, ``-full``.

Presets:

* ``paper``: the paper's settings (C1 = C2 = 64, convolutions and pooling from the input size,
  texture = sigmoid(decoder), AdamW at 5e-3 with 1,000 warm-up steps and cosine decay,
  15,000 steps, K = 4 views, L2 + 0.1 (1 - SSIM) + 0.01 VGG-19 when weights are given).
  Meant for a GPU.
* ``cpu``: what the 2-core CPU affords, each choice measured (README, "The network"):
  C1 = C2 = 16; the encoder goes down to the target size by space-to-depth instead of
  full-size convolutions; the decoder adds a residual to the Lanczos texture (warm start: the
  run starts where ``direct`` starts); fewer steps at a higher learning rate; no SSIM or VGG.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch
from PIL import Image

from geoscaler.color import texture_to_linear
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.methods.learned import fit, loop_config, method_renderer
from geoscaler.methods.registry import (
    MethodOptions,
    MethodResult,
    NetworkFacts,
    RunContext,
    register,
)
from geoscaler.nn.network import (
    VARIANTS,
    GeoScalerNet,
    MeshGeometry,
    NetworkConfig,
    parameter_count,
)
from geoscaler.nn.perceptual import perceptual_loss
from geoscaler.optim.loop import LoopSetup
from geoscaler.optim.losses import PerceptualTerm
from geoscaler.resize.filters import lanczos, reference_textures, target_size
from geoscaler.resize.sizes import SizeRule
from geoscaler.uv.uvmaps import (
    check_square,
    geometry_maps,
    mesh_graph,
    uv_raster,
    vertex_materials,
)


@dataclass(frozen=True)
class Preset:
    """A named set of architecture and training settings."""

    network: NetworkConfig
    optimize: dict[str, Any] = field(default_factory=dict)
    perceptual_weight: float = 0.0


PRESETS = {
    "paper": Preset(
        NetworkConfig(channels=64, graph_channels=64, stem="pool", residual=False),
        {
            "steps": 15_000,
            "lr": 5e-3,
            "weight_decay": 0.01,
            "warmup_steps": 1_000,
            "views_per_step": 4,
            "pool_views": 240,
            "ssim_weight": 0.1,
            "validate_every": 500,
        },
        perceptual_weight=0.01,
    ),
    "cpu": Preset(
        NetworkConfig(
            channels=16, graph_channels=16, warp_channels=4, stem="unshuffle", residual=True
        ),
        {
            "steps": 300,
            "lr": 5e-3,
            "weight_decay": 0.0,
            "warmup_steps": 20,
            "views_per_step": 4,
            "ssim_weight": 0.0,
            "validate_every": 100,
        },
    ),
}
DEFAULT_PRESET = "cpu"
DEFAULT_VARIANT = "full"


def check_variant(name: str) -> str:
    """``name`` when it names a network variant (the one check of ``--variant``)."""
    if name not in VARIANTS:
        raise GeoscalerError(
            f"--variant {name!r}: unknown variant; choose one of {', '.join(VARIANTS)}"
        )
    return name


def check_preset(name: str) -> str:
    """``name`` when it names a preset (the one check of ``--preset``)."""
    if name not in PRESETS:
        raise GeoscalerError(
            f"--preset {name!r}: unknown preset; choose one of {', '.join(PRESETS)}"
        )
    return name


class NetworkModel:
    """The loop's view of the network: its weights are the parameters, its output the
    candidate.

    Args:
        network: the network (on the run's device).
        inputs: per material ``(10, H, W)`` encoder input (None: untextured).
        geometry: the mesh as the network sees it.
        bases: per material ``(3, h, w)`` linear base textures for residual networks.
    """

    def __init__(
        self,
        network: GeoScalerNet,
        inputs: list[torch.Tensor | None],
        geometry: MeshGeometry,
        bases: list[torch.Tensor | None] | None,
    ):
        self.network = network
        self.inputs = inputs
        self.geometry = geometry
        self.bases = bases

    def parameters(self) -> list[torch.Tensor]:
        return list(self.network.parameters())

    def candidate(self) -> tuple[list[torch.Tensor | None], torch.Tensor | None]:
        output = self.network(self.inputs, self.geometry, self.bases)
        return output.textures, output.uvs

    def project(self) -> None:
        """Nothing to clamp: the network's outputs are valid by construction."""


def network_scale(rule: SizeRule) -> int:
    """The whole factor the network's architecture downsamples by: the rule's scale alone."""
    if rule.scale is None or rule.max_size is not None or rule.power_of_two:
        raise GeoscalerError(
            f"sizes {rule.label}: the GeoScaler network downsamples by a whole factor, so it "
            "takes --scale alone; use --method direct for --max-size or --power-of-two"
        )
    return rule.scale


def check_maps_follow(mesh: TexturedMesh, config: NetworkConfig) -> None:
    """Refuse to warp the UVs of a mesh whose other maps (normal, roughness...) read them: they
    would no longer line up with the surface."""
    if not config.uv_warper:
        return
    for material in mesh.materials:
        if material.maps:
            raise GeoscalerError(
                f"material {material.name!r} has other maps ({', '.join(material.maps)}) on the "
                f"UVs that variant {config.variant!r} moves; they would no longer line up: use "
                "--variant base or gcm (UVs kept), or --method direct"
            )


def network_inputs(
    mesh: TexturedMesh, scale: int, device: torch.device, maps: list[np.ndarray | None]
) -> tuple[list[torch.Tensor | None], list[torch.Tensor | None], list[np.ndarray | None]]:
    """Per material: the encoder input, the output texture's UV raster, the Lanczos start.

    The input is the reference map of ``maps`` (resized with Lanczos to ``scale`` times the
    output size when the two do not divide) with its geometry maps: ``(10, sH, sW)``.
    """
    inputs, rasters, starts = [], [], []
    for index, texture in enumerate(maps):
        if texture is None:
            inputs.append(None), rasters.append(None), starts.append(None)
            continue
        height, _ = target_size(*texture.shape[:2], scale)
        size = height * scale
        if texture.shape[0] != size:
            texture = np.asarray(Image.fromarray(texture).resize((size, size), Image.LANCZOS))
        srgb = torch.from_numpy(texture[..., :3].astype(np.float32) / 255).permute(2, 0, 1)
        maps = geometry_maps(uv_raster(mesh, index, size), mesh)
        inputs.append(torch.cat([srgb, maps]).to(device))
        rasters.append(uv_raster(mesh, index, height, device))
        starts.append(lanczos(texture, scale))
    return inputs, rasters, starts


def build_network(
    mesh: TexturedMesh,
    scale: int,
    config: NetworkConfig,
    device: torch.device,
    maps: list[np.ndarray | None] | None = None,
) -> NetworkModel:
    """The network and everything it reads of ``mesh``, ready to train; it starts from
    ``maps`` (default: the protocol's reference maps)."""
    check_square(mesh)
    maps = reference_textures(mesh) if maps is None else maps
    inputs, rasters, starts = network_inputs(mesh, scale, device, maps)
    geometry = MeshGeometry(
        torch.from_numpy(np.asarray(mesh.uvs, np.float32)).to(device),
        torch.from_numpy(np.asarray(mesh.faces, np.int64)).to(device),
        torch.from_numpy(vertex_materials(mesh)).to(device),
        mesh_graph(mesh, device),
        rasters,
    )
    bases = None
    if config.residual:
        bases = [
            None if s is None else texture_to_linear(s, device).permute(2, 0, 1) for s in starts
        ]
    network = GeoScalerNet(config, scale).to(device)
    return NetworkModel(network, inputs, geometry, bases)


def geoscaler_network(
    mesh: TexturedMesh, rule: SizeRule, options: MethodOptions, context: RunContext
) -> MethodResult:
    """Train the GeoScaler network on ``mesh`` and return its texture (and UVs).

    ``options.settings``: ``"variant"`` (base, gcm, uvw, full), ``"preset"`` (cpu, paper),
    ``"vgg19"`` (path of VGG-19 weights for the perceptual term), ``"optimize"`` overrides.
    """
    started = context.clock.now()  # the time budget covers building the network too
    scale = network_scale(rule)
    variant = check_variant(options.settings.get("variant") or DEFAULT_VARIANT)
    preset_name = check_preset(options.settings.get("preset") or DEFAULT_PRESET)
    preset = PRESETS[preset_name]
    renderer = method_renderer(mesh, options, context)
    torch.manual_seed(options.seed)
    config = replace(preset.network, variant=variant)
    check_maps_follow(mesh, config)
    model = build_network(mesh, scale, config, renderer.device, renderer.reference_maps())

    perceptual, perceptual_note = None, "off in this preset"
    if preset.perceptual_weight > 0:
        loss, perceptual_note = perceptual_loss(options.settings.get("vgg19"), renderer.device)
        perceptual = None if loss is None else PerceptualTerm(loss, preset.perceptual_weight)

    loop = loop_config(preset.optimize, options, context)
    facts = NetworkFacts(variant, preset_name, parameter_count(model.network), perceptual_note)
    result = fit(
        mesh,
        rule,
        renderer,
        model,
        loop,
        context,
        started,
        LoopSetup(keeps_uvs=not config.uv_warper, perceptual=perceptual),
    )
    if result.uvs is not None:
        facts.uv_shift_texels = uv_shift(mesh, result.uvs, result.textures)
    result.network = facts
    return result


def uv_shift(
    mesh: TexturedMesh, uvs: np.ndarray, textures: list[np.ndarray | None]
) -> dict[str, float]:
    """Mean and largest distance the warp moved a vertex, in texels of its output texture."""
    sizes = np.array([[0, 0] if t is None else t.shape[1::-1] for t in textures], np.float64)
    materials = vertex_materials(mesh)
    used = materials >= 0
    texels = (uvs - mesh.uvs)[used] * sizes[materials[used]]
    distance = np.linalg.norm(texels, axis=1)
    return {"mean": float(distance.mean()), "max": float(distance.max())}


def preset_steps(settings: Mapping[str, Any]) -> int:
    """The step limit of the preset ``settings`` name (default: :data:`DEFAULT_PRESET`)."""
    return PRESETS[check_preset(settings.get("preset") or DEFAULT_PRESET)].optimize["steps"]


register("geoscaler", geoscaler_network, learned=True, steps=preset_steps)
for _variant in VARIANTS:
    register(
        f"geoscaler-{_variant}",
        geoscaler_network,
        learned=True,
        settings={"variant": _variant},
        steps=preset_steps,
    )
