"""The PROTOCOL.md renderer in OpenGL (moderngl): the GLSL twin of :mod:`geoscaler.render.renderer`.

A view is drawn into a float framebuffer at ``supersample`` x the image size (linear light,
depth-tested, no culling), box-averaged and encoded to sRGB by a second pass. Textures are
``GL_SRGB8_ALPHA8`` with their mip chain built like :func:`geoscaler.render.texture.build_mip_chain`
(linear-light 2 x 2 box, odd rows/columns dropped) and uploaded level by level, so the hardware
decodes sRGB and filters trilinearly over the same levels as the torch sampler.
``tests/test_gl_renderer.py`` holds the two renderers to the same pixels.

Works in any moderngl context: the app's window, or a headless EGL context
(:func:`headless_context`).
"""

from __future__ import annotations

import importlib.resources
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import moderngl
import numpy as np
import torch

from geoscaler.color import linear_to_srgb, texture_to_linear, to_rgb
from geoscaler.errors import GeoscalerError
from geoscaler.mesh import TexturedMesh
from geoscaler.protocol import (
    AMBIENT_RADIANCE,
    IMAGE_SIZE,
    MIN_PERCEPTUAL_ROUGHNESS,
    SUPERSAMPLE,
)
from geoscaler.render.cameras import Camera
from geoscaler.render.lit import (
    LIT_SLOTS,
    SRGB_SLOTS,
    camera_lights,
    decoded_map,
    lit_factors,
    lit_maps,
    vertex_tangents,
)
from geoscaler.render.texture import build_mip_chain
from geoscaler.resize.filters import reference_textures

from .orbit import view_scale

if TYPE_CHECKING:
    from importlib.resources.abc import Traversable

GL_SRGB8_ALPHA8 = 0x8C43
SHADER_PACKAGE = "geoscaler.shaders"
"""The package whose data are the GLSL files (``shaders/`` of the source tree, see setup.py)."""


def shader_files() -> Traversable:
    """The shader files as package data (:func:`importlib.resources.files`), wherever and
    however ``geoscaler.shaders`` is installed (editable, wheel, zip)."""
    try:
        return importlib.resources.files(SHADER_PACKAGE)
    except ModuleNotFoundError as exc:
        raise GeoscalerError(
            f"package {SHADER_PACKAGE} not found; reinstall geoscaler[app]"
        ) from exc


def shader_source(name: str) -> str:
    """The text of the shader file ``name`` (``shaders/<name>`` in the source tree)."""
    resource = shader_files().joinpath(name)
    if not resource.is_file():
        raise GeoscalerError(
            f"shader {name} not found in {SHADER_PACKAGE}; reinstall geoscaler[app]"
        )
    return resource.read_text(encoding="utf-8")


def program(
    ctx: moderngl.Context, vertex: str, fragment: str, defines: dict[str, int] | None = None
) -> moderngl.Program:
    """Compile and link two shader files, with ``#define NAME VALUE`` for each of ``defines``
    (inserted after each file's ``#version`` line)."""
    lines = "".join(f"#define {name} {value}\n" for name, value in (defines or {}).items())

    def source(name: str) -> str:
        version, rest = shader_source(name).split("\n", 1)
        return f"{version}\n{lines}{rest}"

    return ctx.program(vertex_shader=source(vertex), fragment_shader=source(fragment))


def use_screen(ctx: moderngl.Context) -> None:
    """Bind the window's framebuffer again (a headless context has none)."""
    if ctx.screen is not None:
        ctx.screen.use()


def headless_context() -> moderngl.Context:
    """An offscreen OpenGL 4.5 context through EGL (Mesa llvmpipe on machines without a GPU).

    Raises:
        GeoscalerError: no EGL/OpenGL here, with what to install.
    """
    try:
        return moderngl.create_standalone_context(backend="egl", require=450)
    except Exception as error:  # moderngl raises plain Exception for a missing library
        raise GeoscalerError(
            f"no headless OpenGL 4.5 context ({error}); install EGL and Mesa "
            "(apt-get install libegl1 libgl1)"
        ) from error


def to_rgba(texture: np.ndarray) -> np.ndarray:
    """``(H, W, C)`` uint8 texture, C in 1..4, to ``(H, W, 4)`` (grey broadcast, alpha 255)."""
    rgb = to_rgb(texture)
    alpha = np.full(texture.shape[:2] + (1,), 255, dtype=np.uint8)
    return np.ascontiguousarray(np.concatenate([rgb, alpha], axis=2))


def srgb_mip_chain(texture: np.ndarray) -> list[np.ndarray]:
    """The protocol's mip chain of an 8-bit sRGB texture, each level as 8-bit sRGB RGBA.

    Level 0 is the texture itself; coarser levels are 2 x 2 box averages in linear light
    (:func:`geoscaler.render.texture.build_mip_chain`), encoded and rounded to 8 bits to be stored
    in a ``GL_SRGB8_ALPHA8`` texture, as a GPU stores generated mip levels.

    Returns:
        Levels ``(H_l, W_l, 4)`` uint8, row 0 at the top.
    """
    rgba = to_rgba(texture)
    with torch.no_grad():
        levels = build_mip_chain(texture_to_linear(rgba))
    chain = [rgba]
    for level in levels[1:]:
        rgb = linear_to_srgb(level).mul(255.0).round().to(torch.uint8).numpy()
        alpha = np.full(rgb.shape[:2] + (1,), 255, dtype=np.uint8)
        chain.append(np.ascontiguousarray(np.concatenate([rgb, alpha], axis=2)))
    return chain


def upload_texture(ctx: moderngl.Context, chain: list[np.ndarray]) -> moderngl.Texture:
    """A ``GL_SRGB8_ALPHA8`` texture with a mip chain, repeat addressing, trilinear filtering.

    Args:
        chain: the levels from :func:`srgb_mip_chain` (built on any thread; uploading is quick).

    Image rows are flipped on upload so that GL's ``t`` equals the mesh's ``v`` (row 0 of the
    image is ``v = 1``); each level is flipped after it is built, so odd-size levels drop the
    same row as the torch chain does.
    """
    height, width = chain[0].shape[:2]
    gl_texture = ctx.texture((width, height), 4, internal_format=GL_SRGB8_ALPHA8)
    gl_texture.build_mipmaps(0, len(chain) - 1)  # allocates every level
    for index, level in enumerate(chain):
        gl_texture.write(np.ascontiguousarray(level[::-1]).tobytes(), level=index, alignment=1)
    gl_texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    gl_texture.repeat_x = gl_texture.repeat_y = True
    return gl_texture


def linear_mip_chain(values: torch.Tensor) -> list[np.ndarray]:
    """The protocol's mip chain of ``(H, W, 3)`` linear values (a data or normal map as
    :func:`geoscaler.render.lit.decoded_map` reads it), each level ``(H_l, W_l, 4)`` float32
    (alpha 1): kept in float, as the torch sampler keeps them."""
    with torch.no_grad():
        levels = build_mip_chain(values)
    return [
        np.ascontiguousarray(torch.nn.functional.pad(level, (0, 1), value=1.0).numpy())
        for level in levels
    ]


def upload_float_texture(ctx: moderngl.Context, chain: list[np.ndarray]) -> moderngl.Texture:
    """An RGBA float texture with the mip chain of :func:`linear_mip_chain`, repeat addressing,
    trilinear filtering (rows flipped as in :func:`upload_texture`)."""
    height, width = chain[0].shape[:2]
    gl_texture = ctx.texture((width, height), 4, dtype="f4")
    gl_texture.build_mipmaps(0, len(chain) - 1)
    for index, level in enumerate(chain):
        gl_texture.write(np.ascontiguousarray(level[::-1]).tobytes(), level=index)
    gl_texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    gl_texture.repeat_x = gl_texture.repeat_y = True
    return gl_texture


def pan_matrix(pan: tuple[float, float]) -> np.ndarray:
    """``(4, 4)`` shift of the image by ``pan`` in normalised device units (applied to clip)."""
    shift = np.eye(4)
    shift[0, 3], shift[1, 3] = pan
    return shift


class Target:
    """Where one view is drawn: a supersampled float framebuffer and the resolved image.

    Args:
        size: the side of a square target, or ``(width, height)`` in pixels.

    Attributes:
        shape: ``(width, height)`` in pixels.
        image: ``shape`` RGBA8 texture, sRGB-encoded colour, opaque (shown by the app).
        covered: ``shape`` R8 texture, 1 where the mesh covers any supersample.
    """

    def __init__(self, ctx: moderngl.Context, size: int | tuple[int, int], supersample: int):
        width, height = (size, size) if isinstance(size, int) else size
        self.shape = (int(width), int(height))
        self.supersample = supersample
        sampled = (self.shape[0] * supersample, self.shape[1] * supersample)
        self.samples = ctx.texture(sampled, 4, dtype="f4")
        self.samples.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.depth = ctx.depth_renderbuffer(sampled)
        self.draw_fbo = ctx.framebuffer([self.samples], self.depth)
        self.image = ctx.texture(self.shape, 4)
        self.covered = ctx.texture(self.shape, 1)
        self.resolve_fbo = ctx.framebuffer([self.image, self.covered])

    @property
    def size(self) -> int:
        """The width in pixels (the side of a square target)."""
        return self.shape[0]

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """``(image (height, width, 3) uint8 sRGB, foreground (height, width) bool)``, row 0 on
        top."""
        width, height = self.shape
        rgba = np.frombuffer(self.resolve_fbo.read(components=4, attachment=0), np.uint8)
        mask = np.frombuffer(self.resolve_fbo.read(components=1, attachment=1), np.uint8)
        image = rgba.reshape(height, width, 4)[::-1, :, :3]
        covered = mask.reshape(height, width)[::-1] > 0
        return np.ascontiguousarray(image), np.ascontiguousarray(covered)

    def release(self) -> None:
        for thing in (
            self.draw_fbo,
            self.resolve_fbo,
            self.samples,
            self.depth,
            self.image,
            self.covered,
        ):
            thing.release()


class TargetPair:
    """Two targets of one size (made by :meth:`GLRenderer.target_pair`) drawn in one pass by
    :meth:`GLRenderer.render_pair`: the first target's depth buffer, both sample textures as
    colour attachments 0 and 1. Owns them; unpacks as ``first, second = pair``."""

    def __init__(self, ctx: moderngl.Context, targets: tuple[Target, Target]):
        self.targets = targets
        first, second = targets
        self.draw_fbo = ctx.framebuffer([first.samples, second.samples], first.depth)

    def __iter__(self) -> Iterator[Target]:
        return iter(self.targets)

    def release(self) -> None:
        self.draw_fbo.release()
        for target in self.targets:
            target.release()


def set_array(prog: moderngl.Program, name: str, values: list) -> None:
    """Set the uniform array ``name`` (a length-1 array is set from its one value); uniforms the
    compiler removed as unused are skipped."""
    if name in prog:
        prog[name].value = values if len(values) > 1 else values[0]


class Surface:
    """A textured look of the mesh: one texture per material and the UVs they use.

    Args:
        renderer: the mesh's renderer (its context and geometry).
        textures: per material ``(H, W, C)`` uint8 sRGB texture, or None (untextured).
        uvs: UVs for these textures, ``(V, 2)`` per vertex or ``(F, 3, 2)`` per face corner,
            or None for the mesh's own.
        chains: the textures' :func:`srgb_mip_chain`, when already built (e.g. by a worker).
    """

    def __init__(
        self,
        renderer: GLRenderer,
        textures: Sequence[np.ndarray | None],
        uvs: np.ndarray | None = None,
        chains: Sequence[list[np.ndarray] | None] | None = None,
    ):
        ctx = renderer.ctx
        if len(textures) != len(renderer.mesh.materials):
            raise GeoscalerError(
                f"{len(textures)} textures for {len(renderer.mesh.materials)} materials"
            )
        if chains is None:
            chains = [None if t is None else srgb_mip_chain(t) for t in textures]
        self.textures = [None if c is None else upload_texture(ctx, c) for c in chains]
        self.levels = [0 if c is None else len(c) for c in chains]
        corners = renderer.mesh.corner_uvs(uvs)[renderer.face_order].reshape(-1, 2)
        self.uv_buffer = ctx.buffer(np.ascontiguousarray(corners, dtype=np.float32).tobytes())
        self.vao = renderer.mesh_vertex_array([self])

    def release(self) -> None:
        for texture in self.textures:
            if texture is not None:
                texture.release()
        self.vao.release()
        self.uv_buffer.release()


def _upload_map(
    ctx: moderngl.Context, pixels: np.ndarray, slot: str
) -> tuple[moderngl.Texture, int]:
    """A lit map on the GPU and its count of mip levels: sRGB colour as ``GL_SRGB8_ALPHA8``,
    data and normals as float values."""
    if slot in SRGB_SLOTS:
        chain = srgb_mip_chain(pixels)
        return upload_texture(ctx, chain), len(chain)
    chain = linear_mip_chain(decoded_map(pixels, slot, "cpu"))
    return upload_float_texture(ctx, chain), len(chain)


class LitSurface:
    """A lit look of a mesh (PROTOCOL.md, protocol 2): every map of every material that the
    lit render reads, and the corners' normals, tangents and UVs.

    Args:
        renderer: the renderer of the mesh's geometry (its context, positions, face order).
        mesh: the asset to show, the renderer's mesh with other maps or UVs (default: the
            renderer's own); its positions and faces must be the renderer's.
    """

    def __init__(self, renderer: GLRenderer, mesh: TexturedMesh | None = None):
        mesh = renderer.mesh if mesh is None else mesh
        if len(mesh.faces) != len(renderer.mesh.faces):
            raise GeoscalerError("a lit surface needs the renderer's own faces")
        ctx, order = renderer.ctx, renderer.face_order
        uploaded: dict[tuple[int, bool], tuple[moderngl.Texture, int]] = {}
        self.materials: list[tuple[dict[str, tuple[moderngl.Texture, int]], dict]] = []
        for material in mesh.materials:
            maps = {}
            for slot, pixels in lit_maps(material).items():
                key = (id(pixels), slot in SRGB_SLOTS)
                if key not in uploaded:
                    uploaded[key] = _upload_map(ctx, pixels, slot)
                maps[slot] = uploaded[key]
            self.materials.append((maps, lit_factors(material)))
        self.textures = [texture for texture, _ in uploaded.values()]
        tangents = mesh.attributes.get("TANGENT")
        if tangents is None:
            tangents = vertex_tangents(mesh.positions, mesh.faces, mesh.uvs, mesh.normals)
        faces = mesh.faces[order]
        self.buffers = [
            ctx.buffer(np.ascontiguousarray(values[faces].reshape(-1, width), np.float32).tobytes())
            for values, width in ((mesh.normals, 3), (tangents, 4), (mesh.uvs, 2))
        ]
        normals, tangent_buffer, uvs = self.buffers
        self.vao = ctx.vertex_array(
            renderer.lit_program,
            [
                (renderer.positions, "3f", "position"),
                (normals, "3f", "normal"),
                (tangent_buffer, "4f", "tangent"),
                (uvs, "2f", "uv"),
            ],
        )

    def release(self) -> None:
        for thing in (*self.textures, *self.buffers, self.vao):
            thing.release()


class GLRenderer:
    """Renders one mesh, normalised per the protocol, from protocol cameras.

    Args:
        ctx: an OpenGL >= 4.5 moderngl context (``dFdxFine``).
        mesh: the mesh; its geometry is fixed for the renderer's lifetime.
        image_size: output image side in pixels (default: the protocol's).
        supersample: samples per pixel side (default: the protocol's).
    """

    def __init__(
        self,
        ctx: moderngl.Context,
        mesh: TexturedMesh,
        image_size: int = IMAGE_SIZE,
        supersample: int = SUPERSAMPLE,
    ):
        self.ctx = ctx
        self.mesh = mesh
        self.image_size = image_size
        self.supersample = supersample
        self.mesh_programs = {
            views: program(ctx, "mesh.vert", "mesh.frag", {"VIEWS": views}) for views in (1, 2)
        }
        self.lit_program = program(ctx, "lit.vert", "lit.frag")
        self.resolve_program = program(ctx, "fullscreen.vert", "resolve.frag")
        self.empty_vao = ctx.vertex_array(self.resolve_program, [])
        self.face_order = np.argsort(mesh.face_material, kind="stable")
        counts = np.bincount(mesh.face_material, minlength=len(mesh.materials))
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self.ranges = [(int(s) * 3, int(c) * 3) for s, c in zip(starts, counts, strict=True)]
        # One vertex a face corner, faces by material: a layout may give a vertex's corners
        # different UVs (cut charts, :meth:`TexturedMesh.corner_uvs`).
        corners = mesh.normalized_positions()[mesh.faces[self.face_order]].reshape(-1, 3)
        self.positions = ctx.buffer(np.ascontiguousarray(corners, dtype=np.float32).tobytes())
        self.factors = [tuple(float(x) for x in m.base_color_factor[:3]) for m in mesh.materials]

    def reference_surface(self) -> Surface:
        """The mesh's own textures as the protocol's reference maps (larger than 2048 reduced)."""
        return Surface(self, reference_textures(self.mesh))

    def target(self, shape: tuple[int, int] | None = None) -> Target:
        """A new render target of this renderer's supersampling, ``shape`` (width, height)
        pixels (None: the renderer's square image size)."""
        return Target(self.ctx, shape or self.image_size, self.supersample)

    def preview_target(self, shape: tuple[int, int] | None = None) -> Target:
        """A target 8 times cheaper to fill than :meth:`target`'s: half the width and height,
        no supersampling."""
        width, height = shape or (self.image_size, self.image_size)
        return Target(self.ctx, (max(width // 2, 1), max(height // 2, 1)), 1)

    def target_pair(
        self, preview: bool = False, shape: tuple[int, int] | None = None
    ) -> TargetPair:
        """Two targets (of :meth:`target`'s size, or :meth:`preview_target`'s) for
        :meth:`render_pair`."""
        make = self.preview_target if preview else self.target
        return TargetPair(self.ctx, (make(shape), make(shape)))

    def mesh_vertex_array(self, surfaces: Sequence[Surface]) -> moderngl.VertexArray:
        """The mesh with the UVs of one or two surfaces (attributes ``uv``, ``uv_b``)."""
        names = ("uv", "uv_b")
        return self.ctx.vertex_array(
            self.mesh_programs[len(surfaces)],
            [(self.positions, "3f", "position")]
            + [(s.uv_buffer, "2f", name) for s, name in zip(surfaces, names, strict=False)],
        )

    def render(
        self,
        camera: Camera,
        surface: Surface,
        target: Target,
        pan: tuple[float, float] = (0.0, 0.0),
    ) -> Target:
        """Draw ``surface`` from ``camera`` into ``target`` (its ``image`` and ``covered``).

        Args:
            pan: image shift in normalised device units (the app's pan; 0 for protocol views).
        """
        self._draw(camera, [surface], surface.vao, target.draw_fbo, pan)
        self._resolve(target)
        return target

    def render_pair(
        self,
        camera: Camera,
        surfaces: tuple[Surface, Surface],
        targets: TargetPair,
        pan: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """:meth:`render` of two surfaces from one camera in one pass over the triangles, the
        same pixels as two calls at about half the vertex work (what bounds small views)."""
        vao = self.mesh_vertex_array(surfaces)
        try:
            self._draw(camera, surfaces, vao, targets.draw_fbo, pan)
        finally:
            vao.release()
        for target in targets.targets:
            self._resolve(target)

    def _draw(
        self,
        camera: Camera,
        surfaces: Sequence[Surface],
        vao: moderngl.VertexArray,
        fbo: moderngl.Framebuffer,
        pan: tuple[float, float],
    ) -> None:
        """Draw ``surfaces[i]`` into colour attachment ``i`` of ``fbo`` (supersampled)."""
        ctx, prog = self.ctx, vao.program
        self._begin(camera, prog, fbo, pan)
        views = range(len(surfaces))
        for index, (first, count) in enumerate(self.ranges):
            if count == 0:
                continue
            textures = [surface.textures[index] for surface in surfaces]
            for unit, texture in zip(views, textures, strict=True):
                if texture is not None:
                    texture.use(unit)
            prog["base_color_factor"] = self.factors[index]
            set_array(prog, "textured", [texture is not None for texture in textures])
            set_array(prog, "base_color", list(views))
            set_array(prog, "max_level", [float(s.levels[index] - 1) for s in surfaces])
            vao.render(moderngl.TRIANGLES, vertices=count, first=first)
        ctx.disable(moderngl.DEPTH_TEST)

    def render_lit(
        self,
        camera: Camera,
        surface: LitSurface,
        target: Target,
        pan: tuple[float, float] = (0.0, 0.0),
    ) -> Target:
        """Draw ``surface`` lit (protocol 2) from ``camera`` into ``target``."""
        ctx, prog = self.ctx, self.lit_program
        self._begin(camera, prog, target.draw_fbo, pan)
        self._set_lights(camera)
        for (first, count), (maps, factors) in zip(self.ranges, surface.materials, strict=True):
            if count == 0:
                continue
            for unit, slot in enumerate(LIT_SLOTS):
                if slot in maps:
                    maps[slot][0].use(unit)
            set_array(prog, "maps", list(range(len(LIT_SLOTS))))
            set_array(prog, "has_map", [slot in maps for slot in LIT_SLOTS])
            levels = [float(maps[slot][1] - 1) if slot in maps else 0.0 for slot in LIT_SLOTS]
            set_array(prog, "max_level", levels)
            for name, value in factors.items():
                if name in prog:
                    prog[name].value = value
            surface.vao.render(moderngl.TRIANGLES, vertices=count, first=first)
        ctx.disable(moderngl.DEPTH_TEST)
        self._resolve(target)
        return target

    def _set_lights(self, camera: Camera) -> None:
        prog = self.lit_program
        lights = camera_lights(camera)
        prog["eye"] = tuple(float(x) for x in camera.eye)
        set_array(prog, "light_direction", [light.direction for light in lights])
        set_array(prog, "light_irradiance", [light.irradiance for light in lights])
        prog["ambient"] = AMBIENT_RADIANCE
        prog["min_roughness"] = MIN_PERCEPTUAL_ROUGHNESS

    def render_lit_image(
        self, camera: Camera, surface: LitSurface
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`render_image` of a lit surface."""
        target = self.target()
        try:
            return self.render_lit(camera, surface, target).read()
        finally:
            target.release()

    def _begin(
        self,
        camera: Camera,
        prog: moderngl.Program,
        fbo: moderngl.Framebuffer,
        pan: tuple[float, float],
    ) -> None:
        """Clear ``fbo`` and set depth testing and ``prog``'s camera for a draw: a non-square
        ``fbo`` sees less across its shorter side (:func:`~.orbit.view_scale`)."""
        widen = np.diag([*view_scale(*fbo.size), 1.0, 1.0])
        clip = pan_matrix(pan) @ widen @ camera.clip_matrix()
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        self.ctx.depth_func = "<"
        prog["clip_from_world"].write(clip.T.astype(np.float32).tobytes())

    def _resolve(self, target: Target) -> None:
        """Box-average ``target``'s supersamples into its ``image`` and ``covered``."""
        target.resolve_fbo.use()
        target.samples.use(0)
        self.resolve_program["samples"] = 0
        self.resolve_program["factor"] = target.supersample
        self.empty_vao.render(moderngl.TRIANGLES, vertices=3)

    def render_image(self, camera: Camera, surface: Surface) -> tuple[np.ndarray, np.ndarray]:
        """``(image (H, W, 3) uint8 sRGB, foreground (H, W) bool)`` of one view, row 0 on top."""
        target = self.target()
        try:
            return self.render(camera, surface, target).read()
        finally:
            target.release()
