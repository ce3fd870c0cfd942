"""The GeoScaler network, module by module: shapes, parameters, gradients, guards."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from conftest import small_renderer

from geoscaler.errors import GeoscalerError
from geoscaler.mesh import Material, TexturedMesh
from geoscaler.methods import MethodOptions, RunContext, run_method
from geoscaler.methods.network import NetworkModel, build_network
from geoscaler.nn.convolutional import Decoder, Encoder
from geoscaler.nn.geocoding import GeoCoding, GraphConv, sample_at_uvs
from geoscaler.nn.network import VARIANTS, GeoScalerNet, NetworkConfig, parameter_count
from geoscaler.nn.perceptual import PerceptualLoss, VGG19Features, load_vgg19, perceptual_loss
from geoscaler.nn.uvwarper import (
    MAX_OFFSET,
    bounded_offsets,
    fold_free_factor,
    signed_areas,
    warp_plane,
    warp_uvs,
)
from geoscaler.optim.validation import Validation, validation_view_sets
from geoscaler.pipeline.arguments import check_methods
from geoscaler.procedural import demo_mesh
from geoscaler.protocol import Evaluation
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture
from geoscaler.resize.filters import output_sizes
from geoscaler.uv.uvmaps import (
    INPUT_CHANNELS,
    geometry_maps,
    mesh_graph,
    uv_raster,
    vertex_materials,
)

CPU = torch.device("cpu")


def square_mesh(texture: np.ndarray) -> TexturedMesh:
    """Two faces, four vertices, the whole texture on a unit square (the paper's hard case)."""
    positions = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    return TexturedMesh(
        positions=positions,
        faces=np.array([[0, 1, 2], [0, 2, 3]]),
        uvs=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
        normals=np.tile(np.float32([0, 0, 1]), (4, 1)),
        vertex_to_point=np.arange(4),
        face_material=np.zeros(2, np.int64),
        materials=[Material("square", texture, np.ones(4, np.float32))],
    )


def split_at_every_corner(mesh: TexturedMesh) -> TexturedMesh:
    """The same surface stored with one vertex per face corner (as some OBJ exporters do)."""
    corners = mesh.faces.reshape(-1)
    return dataclasses.replace(
        mesh,
        positions=mesh.positions[corners],
        uvs=mesh.uvs[corners],
        normals=mesh.normals[corners],
        vertex_to_point=mesh.vertex_to_point[corners],
        faces=np.arange(len(corners)).reshape(-1, 3),
    )


@pytest.fixture(scope="module")
def small_mesh():
    return demo_mesh(subdivisions=4, texture_size=64)


def small_context(mesh: TexturedMesh, views: int) -> RunContext:
    """What a job hands the method, small: it trains on 128-pixel views (the protocol's: 512)
    and validates on the first ``views`` protocol views at 64 pixels (the protocol: 60 at 512)."""
    renderer = Renderer(mesh, "cpu", Evaluation(image_size=64, views=tuple(range(views))))
    return RunContext(
        renderer=small_renderer(mesh, device="cpu"),
        validation=Validation(validation_view_sets(renderer), output_sizes(mesh, 4)),
    )


# ----------------------------------------------------------------------------- shapes


@pytest.mark.parametrize("stem", ["pool", "unshuffle"])
@pytest.mark.parametrize("scale", [2, 4, 8])
def test_the_encoder_reaches_the_target_size(stem, scale):
    encoder = Encoder(INPUT_CHANNELS, 8, scale, stem)
    features = encoder(torch.rand(1, INPUT_CHANNELS, 64, 64))
    assert features.shape == (1, 8, 64 // scale, 64 // scale)


def test_the_decoder_maps_features_to_rgb_and_can_start_at_zero():
    features = torch.rand(1, 12, 16, 16)
    assert Decoder(12, 8)(features).shape == (1, 3, 16, 16)
    assert torch.equal(Decoder(12, 8, zero_output=True)(features), torch.zeros(1, 3, 16, 16))


def test_geometry_maps_hold_position_normal_and_coverage(small_mesh):
    maps = geometry_maps(uv_raster(small_mesh, 0, 32), small_mesh)
    assert maps.shape == (7, 32, 32)
    covered = maps[6] > 0
    assert torch.all(maps[6][covered] == 1.0)
    normal_length = maps[3:6].norm(dim=0)[covered]
    torch.testing.assert_close(normal_length, torch.ones_like(normal_length))
    assert maps[:3][:, covered].norm(dim=0).max() <= 1.0 + 1e-5  # the unit scene
    assert torch.all(maps[:, ~covered] == 0)


def test_geocoding_keeps_the_shape_of_the_features(small_mesh):
    graph = mesh_graph(small_mesh)
    raster = uv_raster(small_mesh, 0, 16)
    uvs = torch.from_numpy(small_mesh.uvs)
    materials = torch.from_numpy(vertex_materials(small_mesh))
    (out,) = GeoCoding(8, 6)([torch.rand(8, 16, 16)], uvs, materials, graph, [raster])
    assert out.shape == (8, 16, 16)


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_variant_outputs_a_texture_of_the_target_size(small_mesh, variant):
    model = build_network(small_mesh, 4, NetworkConfig(variant, 8, 8, 4), CPU)
    (texture,), uvs = model.candidate()
    assert texture.shape == (16, 16, 3)
    assert texture.min() >= 0 and texture.max() <= 1
    assert (uvs is not None) == (variant in ("uvw", "full"))
    if uvs is not None:
        assert uvs.shape == (len(small_mesh.uvs), 2)


# ----------------------------------------------------------------------------- parameters


def test_parameter_count_at_64_channels():
    """Layer by layer, 4x (two pooling stages), C1 = C2 = 64, 16 warp channels."""
    conv = lambda cin, cout: cin * cout * 9 + cout  # noqa: E731
    linear = lambda cin, cout, bias=True: cin * cout + cout * bias  # noqa: E731
    encoder = conv(10, 64) + 2 * conv(64, 64) + 4 * 2 * conv(64, 64)
    graph_conv = linear(64, 64) + linear(64, 64, bias=False)
    geocoding = linear(64, 64) + 2 * 2 * graph_conv + linear(64, 64)
    warper = conv(16, 16) + conv(16, 2)
    decoder = lambda cin: conv(cin, 64) + conv(64, 64) + conv(64, 3)  # noqa: E731
    expected = {
        "base": encoder + decoder(64),
        "gcm": encoder + geocoding + decoder(64),
        "uvw": encoder + warper + decoder(48),
        "full": encoder + geocoding + warper + decoder(48),
    }
    for variant, count in expected.items():
        assert parameter_count(GeoScalerNet(NetworkConfig(variant), 4)) == count
    assert expected["full"] == 485_429


def randomise_zero_layers(network: torch.nn.Module) -> None:
    """Zero-initialised output layers block gradients to the layers before them at step 0."""
    for parameter in network.parameters():
        if not parameter.any():
            with torch.no_grad():
                parameter.normal_(0, 0.05)


@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("residual", [False, True])
def test_gradients_reach_every_parameter(small_mesh, variant, residual):
    torch.manual_seed(0)
    config = NetworkConfig(variant, 8, 8, 4, stem="pool", residual=residual)
    model = build_network(small_mesh, 4, config, CPU)
    randomise_zero_layers(model.network)
    textures, uvs = model.candidate()
    loss = textures[0].square().sum()
    if uvs is not None:
        loss = loss + (uvs - model.geometry.uvs).square().sum() * 1e3
    loss.backward()
    for name, parameter in model.network.named_parameters():
        assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name


def autograd_nodes(tensor: torch.Tensor) -> set[str]:
    """Names of the backward nodes of the graph that produced ``tensor``."""
    names, seen, stack = set(), set(), [tensor.grad_fn]
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        names.add(type(node).__name__)
        stack.extend(parent for parent, _ in node.next_functions)
    return names


def test_a_training_render_gathers_without_advanced_indexing(small_mesh):
    """The backward of ``x[index]`` (an accumulating ``index_put``) adds in an order that
    depends on thread timing on the CPU: the same seed trained different networks. Every
    differentiable gather is an ``index_select``, whose backward adds in a fixed order."""
    torch.manual_seed(0)
    model = build_network(small_mesh, 4, NetworkConfig("full", 8, 8, 4, stem="pool"), CPU)
    randomise_zero_layers(model.network)
    textures, uvs = model.candidate()
    renderer = small_renderer(small_mesh, device=CPU)
    gbuffer = renderer.rasterize(validation_cameras()[0])
    image = renderer.render(gbuffer, [MipTexture(t) for t in textures], uvs)
    nodes = autograd_nodes(image.sum())
    assert "IndexSelectBackward0" in nodes
    assert not {name for name in nodes if name.startswith(("IndexBackward", "IndexPut"))}


# ----------------------------------------------------------------------------- warp


def test_zero_warp_is_the_identity_on_features_and_uvs():
    plane = torch.rand(5, 12, 12)
    zero = torch.zeros(2, 12, 12)
    assert torch.equal(warp_plane(plane, zero), plane)
    uvs = torch.rand(50, 2) * 3 - 1  # repeat addressing too
    assert torch.equal(warp_uvs(uvs, zero), uvs)


def test_a_fresh_warping_network_keeps_uvs_and_starts_at_its_base(small_mesh):
    config = NetworkConfig("full", 8, 8, 4, stem="unshuffle", residual=True)
    model = build_network(small_mesh, 4, config, CPU)
    (texture,), uvs = model.candidate()
    assert torch.equal(uvs, model.geometry.uvs)
    torch.testing.assert_close(texture, model.bases[0].permute(1, 2, 0).clamp(0, 1))


def test_a_constant_offset_moves_features_by_that_many_texels():
    plane = torch.arange(16.0).view(1, 1, 16).expand(1, 16, 16).clone()  # value = column
    offsets = torch.zeros(2, 16, 16)
    offsets[0] = 0.25
    warped = warp_plane(plane, offsets)
    torch.testing.assert_close(warped[0, :, 3:-3], plane[0, :, 3:-3] + 0.25)


def test_offsets_are_bounded_and_zero_on_the_border():
    offsets = bounded_offsets(torch.randn(2, 10, 10) * 100)
    assert offsets.abs().max() <= MAX_OFFSET
    border = torch.ones(10, 10, dtype=torch.bool)
    border[1:-1, 1:-1] = False
    assert torch.all(offsets[:, border] == 0)


def grid_mesh(n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """UVs of an ``n x n`` vertex grid over [0, 1]^2 and its CCW triangles."""
    t = torch.linspace(0, 1, n)
    v, u = torch.meshgrid(t, t, indexing="ij")
    uvs = torch.stack([u.reshape(-1), v.reshape(-1)], 1)
    i = torch.arange(n - 1)
    a = (i[:, None] * n + i[None, :]).reshape(-1)
    faces = torch.cat(
        [torch.stack([a, a + 1, a + n + 1], 1), torch.stack([a, a + n + 1, a + n], 1)]
    )
    return uvs, faces


def test_the_strongest_warp_neither_folds_nor_leaves_the_unit_square():
    torch.manual_seed(3)
    uvs, faces = grid_mesh(97)  # finer than the 24-texel offset field: many faces per texel
    offsets = bounded_offsets(torch.randn(2, 24, 24) * 100)  # saturated: +-MAX_OFFSET
    moved = warp_uvs(uvs, offsets)
    assert moved.min() >= 0 and moved.max() <= 1
    assert torch.all(signed_areas(moved, faces) > 0)
    assert fold_free_factor(uvs, moved, faces) == 1.0


def test_a_sliver_that_would_flip_makes_the_guard_scale_the_warp_down():
    uvs = torch.tensor([[0.30, 0.50], [0.70, 0.50], [0.50, 0.5004]])
    faces = torch.tensor([[0, 1, 2]])
    moved = uvs.clone()
    moved[2, 1] -= 0.001  # the apex crosses the base: the face flips
    factor = fold_free_factor(uvs, moved, faces)
    assert 0 < factor < 1
    assert signed_areas(uvs + factor * (moved - uvs), faces)[0] > 0


# ----------------------------------------------------------------------------- graph


def test_graph_convolution_weights_neighbours_by_edge_length():
    mesh = square_mesh(np.zeros((4, 4, 3), np.uint8))
    graph = mesh_graph(mesh)
    layer = GraphConv(1, 1)
    with torch.no_grad():
        layer.theta1.weight.fill_(2.0), layer.theta1.bias.fill_(0.0)
        layer.theta2.weight.fill_(1.0)
    features = torch.tensor([[1.0], [0.0], [0.0], [0.0]])
    out = layer(features, graph)[:, 0]
    side, diagonal = 2 / np.sqrt(2), 2.0  # the unit scene: the corners at distance 1
    # Point 0 has neighbours 1, 2, 3 (all zero); points 1 and 3 see it along a side, point 2
    # along the diagonal.
    expected = torch.tensor([2.0, side, diagonal, side], dtype=torch.float32)
    torch.testing.assert_close(out, expected)


def test_graph_convolution_gradcheck():
    mesh = square_mesh(np.zeros((4, 4, 3), np.uint8))
    graph = mesh_graph(mesh)
    graph.lengths = graph.lengths.double()
    layer = GraphConv(3, 2).double()
    features = torch.rand(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda f: layer(f, graph), (features,))


def test_warp_and_vertex_sampling_gradcheck():
    plane = torch.rand(2, 6, 6, dtype=torch.float64, requires_grad=True)
    offsets = (torch.rand(2, 6, 6, dtype=torch.float64) * 0.2).requires_grad_(True)
    uvs = torch.rand(7, 2, dtype=torch.float64) * 0.8 + 0.1
    assert torch.autograd.gradcheck(warp_plane, (plane, offsets))
    assert torch.autograd.gradcheck(lambda p: sample_at_uvs(p, uvs), (plane,))


def test_an_isolated_vertex_gets_no_messages_and_unused_vertices_no_samples():
    mesh = square_mesh(np.zeros((4, 4, 3), np.uint8))
    mesh = dataclasses.replace(
        mesh,
        positions=np.vstack([mesh.positions, [[0, 0, 1]]]).astype(np.float32),
        uvs=np.vstack([mesh.uvs, [[0.5, 0.5]]]).astype(np.float32),
        normals=np.vstack([mesh.normals, [[0, 0, 1]]]).astype(np.float32),
        vertex_to_point=np.arange(5),
    )
    graph = mesh_graph(mesh)
    assert graph.num_points == 5 and not graph.vertex_used[4]
    features = torch.ones(5, 3)
    assert torch.all(graph.neighbour_sum(features)[4] == 0)
    assert torch.all(graph.neighbour_sum(features)[:4] > 0)
    assert torch.all(graph.pool_vertices(features)[4] == 0)
    assert vertex_materials(mesh)[4] == -1


def test_vertex_sampling_averages_the_uv_duplicates_of_a_point():
    mesh = square_mesh(np.zeros((4, 4, 3), np.uint8))
    # Vertex 4 is point 0 again, at another UV (a seam), used by a third face.
    mesh = dataclasses.replace(
        mesh,
        positions=np.vstack([mesh.positions, mesh.positions[:1]]).astype(np.float32),
        uvs=np.vstack([mesh.uvs, [[1.0, 1.0]]]).astype(np.float32),
        normals=np.vstack([mesh.normals, mesh.normals[:1]]).astype(np.float32),
        vertex_to_point=np.array([0, 1, 2, 3, 0]),
        faces=np.array([[0, 1, 2], [0, 2, 3], [4, 1, 3]]),
        face_material=np.zeros(3, np.int64),
    )
    graph = mesh_graph(mesh)
    plane = torch.arange(4.0).view(1, 2, 2)  # rows top to bottom: v = 0.75, 0.25
    uvs = torch.from_numpy(mesh.uvs)
    samples = GeoCoding(1, 1).vertex_features([plane], uvs, torch.zeros(5, dtype=torch.long))
    torch.testing.assert_close(samples[:, 0], torch.tensor([2.0, 3.0, 1.0, 0.0, 1.0]))
    pooled = graph.pool_vertices(samples)
    torch.testing.assert_close(pooled[:, 0], torch.tensor([1.5, 3.0, 1.0, 0.0]))


def test_a_mesh_split_at_every_corner_gives_the_same_graph(small_mesh):
    welded = mesh_graph(small_mesh)
    split = mesh_graph(split_at_every_corner(small_mesh))
    assert split.num_points == welded.num_points
    edges = lambda g: set(zip(g.sources.tolist(), g.targets.tolist(), strict=True))  # noqa: E731
    assert edges(split) == edges(welded)
    model = build_network(split_at_every_corner(small_mesh), 4, NetworkConfig("full", 8, 8, 4), CPU)
    (texture,), uvs = model.candidate()
    assert texture.shape == (16, 16, 3) and uvs.shape == (len(small_mesh.faces) * 3, 2)


# ----------------------------------------------------------------------------- skip residual


def checker(size: int, cell: int) -> np.ndarray:
    index = np.arange(size) // cell
    board = ((index[:, None] + index[None, :]) % 2 * 255).astype(np.uint8)
    return np.repeat(board[..., None], 3, axis=2)


def fit_square(skip: bool, steps: int = 80) -> float:
    """PSNR (dB) of a GeoCoding network fitted to a 2x-downsampled checkerboard that covers a
    two-face square: four vertices cannot carry the pattern, the skip residual can."""
    torch.manual_seed(0)
    texture = checker(32, cell=4)
    model = build_network(
        square_mesh(texture), 2, NetworkConfig("gcm", 16, 16, stem="unshuffle"), CPU
    )
    model.network.geocoding.skip = skip
    target = torch.from_numpy(texture[::2, ::2].astype(np.float32) / 255)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(steps):
        optimizer.zero_grad()
        (output,), _ = model.candidate()
        loss = (output - target).square().mean()
        loss.backward()
        optimizer.step()
    return float(-10 * torch.log10(loss.detach()))


def test_the_two_face_square_trains_with_the_skip_residual_and_not_without():
    assert fit_square(skip=True) > 40.0
    assert fit_square(skip=False) < 15.0


# ----------------------------------------------------------------------------- VGG-19


@pytest.fixture(scope="module")
def vgg_file(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("vgg") / "vgg19-random.pth"
    state = VGG19Features().state_dict()
    state["classifier.0.weight"] = torch.zeros(2, 2)  # torchvision files carry these too
    torch.save(state, path)
    return path, state


def test_vgg19_loads_from_a_torchvision_style_checkpoint(vgg_file):
    path, state = vgg_file
    model = load_vgg19(path)
    for key, value in model.state_dict().items():
        assert torch.equal(value, state[key]), key
    assert not any(p.requires_grad for p in model.parameters())


def test_the_perceptual_loss_is_zero_for_equal_images_and_differentiable(vgg_file):
    loss = PerceptualLoss(load_vgg19(vgg_file[0]))
    reference = torch.rand(32, 32, 3)
    assert float(loss(reference, reference)) == 0.0
    image = torch.rand(32, 32, 3, requires_grad=True)
    value = loss(image, reference)
    value.backward()
    assert value > 0 and image.grad.abs().sum() > 0


def test_bad_vgg19_files_give_clear_errors(tmp_path):
    with pytest.raises(GeoscalerError, match="no such file"):
        load_vgg19(tmp_path / "missing.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(GeoscalerError, match="not a readable torch checkpoint"):
        load_vgg19(tmp_path / "junk.pth")
    torch.save({"features.0.weight": torch.zeros(1)}, tmp_path / "other.pth")
    with pytest.raises(GeoscalerError, match="not VGG-19 weights"):
        load_vgg19(tmp_path / "other.pth")


def test_without_weights_the_perceptual_term_is_off_and_says_so(monkeypatch, tmp_path):
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
    loss, note = perceptual_loss(None, CPU)
    assert loss is None and note.startswith("off")


def test_torchvisions_cache_is_used_when_it_holds_the_weights(monkeypatch, tmp_path, vgg_file):
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "vgg19-dcbb9e9d.pth").write_bytes(vgg_file[0].read_bytes())
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path))
    loss, note = perceptual_loss(None, CPU)
    assert isinstance(loss, PerceptualLoss) and "vgg19-dcbb9e9d.pth" in note


# ----------------------------------------------------------------------------- the method


def test_the_same_seed_trains_the_same_network(small_mesh):
    def train(seed: int):
        options = MethodOptions(device="cpu", seed=seed, steps=3)
        context = small_context(small_mesh, views=2)
        result = run_method("geoscaler-full", small_mesh, 4, options, context)
        return result.textures[0], result.uvs

    first, again, other = train(0), train(0), train(1)
    assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    assert not np.array_equal(first[1], other[1])


@pytest.mark.parametrize("name", ["geoscaler-base", "geoscaler-uvw"])
def test_the_method_returns_8bit_textures_and_valid_uvs(small_mesh, name):
    options = MethodOptions(device="cpu", steps=2, settings={"optimize": {"pool_views": 2}})
    result = run_method(name, small_mesh, 4, options, small_context(small_mesh, views=2))
    (texture,) = result.textures
    assert texture.dtype == np.uint8 and texture.shape == (16, 16, 3)
    assert result.network.variant == name.split("-")[1]
    assert result.network.perceptual == "off in this preset"
    if name == "geoscaler-uvw":
        assert result.uvs.shape == small_mesh.uvs.shape
        assert result.uvs.min() >= 0 and result.uvs.max() <= 1
        areas = signed_areas(torch.from_numpy(result.uvs), torch.from_numpy(small_mesh.faces))
        before = signed_areas(torch.from_numpy(small_mesh.uvs), torch.from_numpy(small_mesh.faces))
        assert torch.all(areas * before > 0)
        assert result.network.uv_shift_texels["max"] <= MAX_OFFSET * 2**0.5 + 1e-4
    else:
        assert result.uvs is None


def test_non_square_textures_are_refused_clearly():
    mesh = square_mesh(np.zeros((32, 64, 3), np.uint8))
    with pytest.raises(GeoscalerError, match="square textures only"):
        build_network(mesh, 2, NetworkConfig("base", 8, 8), CPU)


def test_the_model_exposes_the_network_weights(small_mesh):
    model = build_network(small_mesh, 4, NetworkConfig("gcm", 8, 8), CPU)
    assert isinstance(model, NetworkModel)
    assert len(model.parameters()) == len(list(model.network.parameters()))


def test_the_paper_preset_trains_with_the_perceptual_term_from_a_file(small_mesh, vgg_file):
    options = MethodOptions(
        device="cpu",
        steps=1,
        settings={
            "preset": "paper",
            "vgg19": str(vgg_file[0]),
            "optimize": {"pool_views": 1, "validate_every": 1},
        },
    )
    result = run_method("geoscaler-gcm", small_mesh, 4, options, small_context(small_mesh, 1))
    assert result.network.perceptual == f"VGG-19 from {vgg_file[0]}"
    assert result.network.preset == "paper" and result.loop.steps == 1
    assert result.textures[0].shape == (16, 16, 3)


def test_unknown_variants_and_presets_are_refused(small_mesh):
    for extra, message in [({"variant": "tiny"}, "variant 'tiny'"), ({"preset": "x"}, "preset")]:
        with pytest.raises(GeoscalerError, match=message):
            run_method("geoscaler", small_mesh, 4, MethodOptions(device="cpu", settings=extra))


# ----------------------------------------------------------------------------- command line


def test_variants_become_rows_of_their_own_in_compare_and_bench():
    names = check_methods("bicubic,geoscaler,direct", "base,full")
    assert names == ["bicubic", "geoscaler-base", "geoscaler-full", "direct"]
    assert check_methods("geoscaler-uvw") == ["geoscaler-uvw"]
    with pytest.raises(GeoscalerError, match="list geoscaler in --methods"):
        check_methods("bicubic", "base")
    with pytest.raises(GeoscalerError, match="--variant 'big': unknown variant"):
        check_methods("geoscaler", "big")
