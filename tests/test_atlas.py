"""Repacking a UV atlas: charts scaled by their footprint, packed as similarities,
the guards, and the bake into the new layout."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from clocks import TickingClock
from mesh_support import ribbon_mesh
from PIL import Image

from geoscaler.clock import Budget, ManualClock
from geoscaler.color import srgb_to_linear
from geoscaler.mesh import Material, TexturedMesh, compute_vertex_normals
from geoscaler.render.cameras import validation_cameras
from geoscaler.render.encoded import EncodedMipTexture
from geoscaler.render.renderer import Renderer
from geoscaler.render.texture import MipTexture, UVFootprint
from geoscaler.render.views import ViewSet
from geoscaler.resize.filters import resize_float
from geoscaler.resize.sizes import COLOR, DATA, NORMAL
from geoscaler.uv import atlas as atlas_module
from geoscaler.uv import packing
from geoscaler.uv.atlas import (
    ALIGNMENT,
    ALLOCATION_EXPONENT,
    CUT_GAIN,
    LEAST_GAIN,
    alignment_for,
    atlas_problems,
    chart_footprint,
    cut_lengths,
    density_for_gain,
    layout_groups,
    plan_charts,
    planned_scales,
    repack,
)
from geoscaler.uv.bake import ChartMaps, bake, decode, decoding, encode
from geoscaler.uv.detail import LostDetail
from geoscaler.uv.packing import (
    Charts,
    PackingError,
    chart_texels,
    overlapping_texels,
    pack,
    padding_violations,
)
from geoscaler.uv.uvmaps import chart_labels, cut_charts

SIZE = 64


def cube_mesh(texture_size: int = 128, chart_side: float = 0.12) -> TexturedMesh:
    """A cube whose six faces are six square charts of ``chart_side`` in a 3 x 2 grid: about
    9 % of the texture used, as a scan's atlas."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    positions, uvs, faces = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
            normal = np.eye(3)[axis] * sign
            if sign < 0:
                u, v = v, u
            base = len(positions)
            for cu, cv in corners:
                positions.append(0.5 * normal + (cu - 0.5) * u + (cv - 0.5) * v)
            index = axis * 2 + (sign > 0)
            origin = np.array([0.05 + 0.3 * (index % 3), 0.1 + 0.4 * (index // 3)])
            uvs.extend(origin + chart_side * corners)
            faces.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    positions = np.array(positions, np.float32)
    faces = np.array(faces, np.int64)
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (texture_size, texture_size, 3), dtype=np.uint8)
    vertex_to_point = np.arange(len(positions))
    return TexturedMesh(
        positions=positions,
        faces=faces,
        uvs=np.array(uvs, np.float32),
        normals=compute_vertex_normals(positions, faces, vertex_to_point),
        vertex_to_point=vertex_to_point,
        face_material=np.zeros(len(faces), np.int64),
        materials=[Material("cube", texture)],
    )


def footprint_ids(mesh: TexturedMesh, weights: list[int]) -> list[torch.Tensor]:
    """Fake G-buffer face ids: face ``f`` seen by ``weights[f // 2]`` samples (two faces a
    chart)."""
    return [torch.tensor(np.repeat(np.arange(len(mesh.faces)), np.repeat(weights, 2)))]


def test_footprint_counts_the_samples_of_each_chart():
    charts = np.array([0, 0, 1, 2])
    ids = [torch.tensor([0, 1, 1, 3]), torch.tensor([2, 3])]
    np.testing.assert_array_equal(chart_footprint(charts, ids), [3.0, 1.0, 2.0])


def test_planned_scales_minimise_the_error_the_samples_see_for_the_same_texels():
    area = np.array([1.0, 1.0, 4.0])
    scales = planned_scales(np.array([1.0, 4.0, 4.0]), area)
    # density ~ (samples / area) ^ (1 / (2 + g)), g = log2 10^0.5: the squared error's fall
    # per doubling of the density at 5 dB per halving; then the original total area
    assert ALLOCATION_EXPONENT == pytest.approx(1 / (2 + math.log2(10**0.5)))
    np.testing.assert_allclose(scales / scales[0], [1.0, 4.0**ALLOCATION_EXPONENT, 1.0])
    np.testing.assert_allclose((scales**2 * area).sum(), area.sum())


def test_detail_weighs_a_chart_as_its_samples_do():
    area = np.ones(3)
    scales = planned_scales(np.array([2.0, 2.0, 8.0]), area, np.array([1.0, 4.0, 1.0]))
    assert scales[1] == pytest.approx(scales[2])
    assert scales[1] / scales[0] == pytest.approx(4.0**ALLOCATION_EXPONENT)


def test_a_chart_of_flat_colour_keeps_a_quarter_of_the_median_density():
    scales = planned_scales(np.array([4.0, 4.0, 4.0]), np.ones(3), np.array([1.0, 1.0, 0.0]))
    assert scales[2] == pytest.approx(0.25 * scales[0])


def test_hidden_charts_keep_a_quarter_of_the_median_density():
    scales = planned_scales(np.array([4.0, 4.0, 0.0]), np.ones(3))
    assert scales[2] == pytest.approx(0.25 * scales[0])


def test_a_chart_that_loses_more_detail_gets_more_texels_for_the_same_samples():
    mesh = cube_mesh()
    lost = LostDetail(energy=np.repeat([16.0, 1, 1, 1, 1, 1], 2), texels=np.ones(12))
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256, lost=lost)
    assert atlas.planned[0] == pytest.approx(16.0**ALLOCATION_EXPONENT * atlas.planned[1])
    np.testing.assert_allclose(atlas.planned[2:], atlas.planned[1])


def test_repack_raises_the_density_of_a_sparse_atlas():
    mesh = cube_mesh()
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256)
    assert atlas.moved and atlas.kept == {}
    assert atlas.facts.charts == 6
    # six squares of 0.12 side: three abreast, each up to a third of the side less padding
    assert 1.5 < atlas.facts.k < 64 / 3 / (0.12 * 64)
    assert atlas.uvs.min() >= 0 and atlas.uvs.max() <= 1
    assert atlas.uvs.shape == (len(mesh.faces), 3, 2)  # a UV per face corner
    assert atlas.facts.charts_cut == 0 and not atlas.facts.cut  # no chart spans half
    assert atlas.facts.vertices_added == 0
    assert len(mesh.with_uvs(atlas.uvs).uvs) == len(mesh.uvs)  # every vertex keeps one UV


def test_a_layout_sparser_than_half_the_own_one_is_not_searched_for(monkeypatch):
    # equal footprints and equal squares: k is the packed scale, texels per unit over the
    # atlas's side; the search starts no sparser than LEAST_GAIN of the own layout's
    mesh = cube_mesh()
    sparsest = []
    pack = atlas_module.pack

    def recording_pack(*args, **kwargs):
        sparsest.append(kwargs["sparsest"])
        return pack(*args, **kwargs)

    monkeypatch.setattr(atlas_module, "pack", recording_pack)
    repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256, align=False)
    assert sparsest == [pytest.approx(LEAST_GAIN * SIZE)]


def test_each_chart_moves_by_a_similarity_at_its_planned_scale():
    mesh = cube_mesh()
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [40, 10, 10, 10, 10, 10]), 256)
    np.testing.assert_allclose(atlas.scales, atlas.planned, rtol=1e-9)
    # 4x the samples: 4^ALLOCATION_EXPONENT the side
    assert atlas.planned[0] == pytest.approx(4.0**ALLOCATION_EXPONENT * atlas.planned[1])
    for matrix in atlas.linear:
        signs = matrix / np.abs(matrix).max()
        assert sorted(np.abs(signs).ravel().round(12).tolist()) == [0, 0, 1, 1]
    mapped = np.einsum("fij,fkj->fki", atlas.linear[chart_labels(mesh)], mesh.uvs[mesh.faces])
    mapped += atlas.offset[chart_labels(mesh)][:, None]
    np.testing.assert_allclose(mapped, atlas.uvs, atol=1e-6)


def test_the_new_layout_passes_every_guard():
    mesh = cube_mesh()
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [40, 10, 20, 10, 5, 10]), 256)
    assert atlas_problems(mesh, atlas) == []
    texels, labels = chart_texels(atlas.uvs, atlas.chart_of_face, SIZE)
    assert len(overlapping_texels(texels, labels)) == 0
    assert padding_violations(texels, labels, SIZE, atlas.padding) == 0


def test_aligned_scales_are_the_grid_times_powers_of_two_at_most_the_grid():
    planned = np.array([5.0, 3.0, 2.0, 1.5, 0.7])
    tpu, size = 128.0, 64
    aligned = packing.scales_at(planned * size / tpu, tpu, size, cap=4.0, aligned=True)
    np.testing.assert_allclose(aligned * tpu / size, [4.0, 2.0, 2.0, 1.0, 0.5])


def test_capped_scales_give_no_chart_more_texels_than_the_original():
    planned = np.array([5.0, 3.0, 2.0, 0.7])
    tpu, size = 128.0, 64
    capped = packing.scales_at(planned * size / tpu, tpu, size, cap=2.5)
    np.testing.assert_allclose(capped * tpu / size, [2.5, 2.5, 2.0, 0.7])
    assert packing.scales_at(planned, tpu, size, cap=None) is planned


def test_the_filling_density_counts_capped_charts_at_their_cap():
    area, scales, size = np.array([0.5, 0.5]), np.array([1.0, 2.0]), 10
    # uncapped: (t / 10)^2 (0.5 + 0.5 * 4) = 1
    assert packing.filling_density(area, scales, size, None) == pytest.approx(10 / 2.5**0.5)
    # the second chart capped at 1.2: 0.5 * 1.2^2 + 0.5 (t / 10)^2 = 1
    assert packing.filling_density(area, scales, size, 1.2) == pytest.approx(10 * 0.56**0.5)
    # both capped at 1.0 cover half the atlas: the density where the first reaches its cap
    assert packing.filling_density(area, scales, size, 1.0) == pytest.approx(10.0)


def test_an_unaligned_layout_gives_no_chart_more_texels_than_the_original():
    mesh = cube_mesh()
    footprints = footprint_ids(mesh, [40, 10, 20, 10, 5, 10])
    uncapped = repack(mesh, [(SIZE, SIZE)], footprints, 256, align=False)
    cap = 0.8 * uncapped.planned.max()
    atlas = repack(mesh, [(SIZE, SIZE)], footprints, 256, [cap], align=False)
    assert atlas.moved and atlas.alignments == [1]
    assert atlas.planned.max() == pytest.approx(cap, rel=1e-9)
    assert atlas_problems(mesh, atlas) == []


def test_the_density_for_a_gain_follows_the_caps_and_the_aligned_steps():
    scales, weights, size = np.ones(2), np.ones(2), 10  # k is the density over 10
    assert density_for_gain(1.5, scales, weights, size, None) == pytest.approx(15.0)
    assert density_for_gain(1.5, scales, weights, size, 2.0) == pytest.approx(15.0)
    # aligned to a cap of 2: k is 1 from density 10 to 20, then 2
    assert density_for_gain(1.0, scales, weights, size, 2.0, aligned=True) == pytest.approx(10.0)
    assert density_for_gain(1.5, scales, weights, size, 2.0, aligned=True) == pytest.approx(20.0)
    assert density_for_gain(3.0, scales, weights, size, 2.0) == np.inf  # capped at 2


def test_charts_are_aligned_only_where_the_far_views_minify_the_texture():
    mesh = cube_mesh()
    # a cube side is 7.7 texels of 64 (magnified far away), 983 of 8192 (minified)
    assert alignment_for(mesh, mesh.faces, 64, 256) == 1
    assert alignment_for(mesh, mesh.faces, 8192, 256) == ALIGNMENT == 16


def test_aligned_charts_cover_power_of_two_blocks_of_the_original_on_its_grid():
    mesh = cube_mesh()
    size, detail = 256, 2.0  # 128 samples a side: a far sample spans 1.2 texels, minified
    atlas = repack(
        mesh, [(size, size)], footprint_ids(mesh, [40, 10, 20, 10, 5, 10]), 128, [detail]
    )
    assert atlas.moved and atlas.alignments == [ALIGNMENT]
    steps = np.log2(atlas.planned / detail)
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)
    assert steps.max() <= 0  # never more texels than the original has
    texels = atlas.offset * size / ALIGNMENT
    np.testing.assert_allclose(texels, np.round(texels), atol=1e-9)
    assert atlas_problems(mesh, atlas) == []
    off_grid = replace(atlas, offset=atlas.offset + 1.0 / size)
    assert f"charts off the {ALIGNMENT}-texel grid" in " ".join(atlas_problems(mesh, off_grid))


def test_the_same_input_gives_the_same_uvs():
    mesh = cube_mesh()
    ids = footprint_ids(mesh, [40, 10, 20, 10, 5, 10])
    first = repack(mesh, [(SIZE, SIZE)], ids, 256)
    second = repack(mesh, [(SIZE, SIZE)], ids, 256)
    np.testing.assert_array_equal(first.uvs, second.uvs)


def test_guards_name_an_overlap_a_flip_and_a_wrong_scale():
    mesh = cube_mesh()
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256)
    moved = replace(atlas, uvs=atlas.uvs.copy(), planned=atlas.planned.copy())
    charts = chart_labels(mesh)
    moved.uvs[charts == 1] = moved.uvs[charts == 0]  # onto chart 0
    problems = " ".join(atlas_problems(mesh, moved))
    assert "covered by two charts" in problems and "not moved by their chart's map" in problems
    flipped = replace(atlas, uvs=atlas.uvs.copy())
    faces = charts == 2
    centre = flipped.uvs[faces].reshape(-1, 2).mean(axis=0)
    flipped.uvs[faces, :, 0] = 2 * centre[0] - flipped.uvs[faces, :, 0]  # mirrored in place
    assert "2 faces flipped" in " ".join(atlas_problems(mesh, flipped))
    wrong = replace(atlas, planned=atlas.planned * 1.01)
    assert atlas_problems(mesh, wrong)[0] == "6 charts not at their planned scale"


def test_padding_violations_count_charts_closer_than_the_padding():
    texels = np.array([0, 3])  # texels (0, 0) and (0, 3) of an 8 x 8 grid: 3 apart
    labels = np.array([0, 1])
    assert padding_violations(texels, labels, 8, 3) == 0
    assert padding_violations(texels, labels, 8, 4) == 2  # each sees the other


def test_padding_violations_are_the_texels_that_see_another_chart_wrapping_around():
    rng = np.random.default_rng(3)
    size, padding = 12, 3
    texels = rng.choice(size * size, 20, replace=False)
    labels = rng.integers(0, 4, 20)
    texels, labels = np.r_[texels, texels[:2]], np.r_[labels, labels[:2] + 1]  # two overlaps
    grid = np.full((size, size), -1)
    grid.reshape(-1)[texels] = labels
    grid.reshape(-1)[texels[:2]] = -1  # overlaps count for no chart
    expected = 0
    for row, col in zip(*np.nonzero(grid >= 0), strict=True):
        near = [
            grid[(row + dy) % size, (col + dx) % size]
            for dy in range(-padding + 1, padding)
            for dx in range(-padding + 1, padding)
        ]
        expected += any(other >= 0 and other != grid[row, col] for other in near)
    assert expected > 0
    assert padding_violations(texels, labels, size, padding) == expected


def test_a_face_covers_the_texels_of_the_samples_inside_it_edges_included():
    # a right triangle on a 4 x 4 grid, two samples a side: its legs run through the centres of
    # samples 0 and 5 (u = 0.0625, 0.6875 in sample units 0.5, 5.5), its hypotenuse through
    # the samples where column + row = 5 (top-left origin, rows downwards from v = 1)
    corners = np.array([[[0.0625, 0.9375], [0.6875, 0.9375], [0.0625, 0.3125]]])
    texels, labels = chart_texels(corners, np.array([3]), 4)
    covered = {(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (2, 0)}  # (row, column) of texels
    assert {divmod(int(t), 4) for t in texels} == covered
    assert (labels == 3).all()


def test_a_face_across_the_border_wraps_onto_the_grid():
    corners = np.array([[[-0.25, 0.5], [0.1, 0.5], [0.1, 0.6]]])  # u < 0: the right-hand side
    texels, _ = chart_texels(corners, np.array([0]), 10, supersample=1)
    assert {divmod(int(t), 10) for t in texels} == {(4, 9), (4, 0)}


def test_chart_coverage_agrees_with_a_test_of_every_sample():
    rng = np.random.default_rng(7)
    for trial in range(40):
        corners = rng.uniform(-0.2, 1.2, (12, 3, 2))
        if trial % 2:  # corners on sample centres: samples on edges
            corners = (np.floor(corners * 16) + 0.5) / 16
        labels = rng.integers(0, 4, 12)
        texels, found = chart_texels(corners, labels, 8)
        assert set(zip(texels.tolist(), found.tolist(), strict=True)) == covered_by_every_sample(
            corners, labels, 8, 2
        )


def covered_by_every_sample(corners, labels, size, supersample):
    """``{(flat texel, label)}``: a sample inside a face (edges included) covers its texel; a
    face with no area covers the samples on its segment."""
    grid = size * supersample
    centres = (np.arange(grid) + 0.5) / grid
    u, v = np.meshgrid(centres, 1.0 - centres)  # rows downwards from v = 1
    found = set()
    for face, label in zip(corners, labels, strict=True):
        for shift_u in (-1, 0, 1):  # repeat addressing: the face's copies one tile away
            for shift_v in (-1, 0, 1):
                (au, av), (bu, bv), (cu, cv) = face - [shift_u, shift_v]
                sides = [
                    (qu - pu) * (v - pv) - (qv - pv) * (u - pu)
                    for (pu, pv), (qu, qv) in (((au, av), (bu, bv)), ((bu, bv), (cu, cv)),
                                               ((cu, cv), (au, av)))
                ]  # fmt: skip
                hair = 1e-12
                inside = np.all([s >= -hair for s in sides], axis=0) | np.all(
                    [s <= hair for s in sides], axis=0
                )
                low, high = (face - [shift_u, shift_v]).min(0), (face - [shift_u, shift_v]).max(0)
                inside &= (u >= low[0]) & (u <= high[0]) & (v >= low[1]) & (v <= high[1])
                for row, col in zip(*np.nonzero(inside), strict=True):
                    texel = (row // supersample) * size + col // supersample
                    found.add((int(texel), int(label)))
    return found


def test_used_atlases_outlive_their_packing_a_bounded_while(monkeypatch):
    # xatlas may hang destroying an atlas whose worker thread is still going back to sleep
    monkeypatch.setattr(packing, "_retired", type(packing._retired)())
    clock = ManualClock()
    atlases = [object() for _ in range(22)]
    for atlas in atlases[:20]:
        packing._retire(atlas, clock)
    assert [a for _, a in packing._retired] == atlases[12:20]  # the last 8 packings' own
    clock.set(0.5)
    packing._retire(atlases[20], clock)  # 0.5 s later: all kept within the count
    assert len(packing._retired) == packing.RETIRED_ATLASES
    clock.set(1.4)
    packing._retire(atlases[21], clock)  # at 1.4 s: those idle for over a second are gone
    assert [a for _, a in packing._retired] == [atlases[20], atlases[21]]


def test_charts_larger_than_the_atlas_are_refused_not_shrunk():
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    charts = Charts(np.array([[0, 1, 2], [0, 2, 3]]), uvs, np.zeros(4, np.int64), 1)
    packed = pack(charts, np.ones(1), 32, 2, rotate=False)
    assert packed.linear[0, 0, 0] * 32 <= 32 - 2  # within the atlas and its padding
    with pytest.raises(PackingError):  # 2000 texels of padding leave no room
        pack(charts, np.ones(1), 32, 2000, rotate=False)


def squares(count: int, side: float) -> Charts:
    """``count`` squares of ``side`` in a row, one chart each."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64) * side
    uvs = np.concatenate([corners + [index * 2 * side, 0] for index in range(count)])
    faces = np.concatenate([[[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]]
                            for i in range(count)])  # fmt: skip
    return Charts(faces, uvs, np.repeat(np.arange(count), 4), count)


def test_the_packing_leaves_the_padding_asked_between_charts_not_twice_it():
    # xatlas pads every chart by its own padding: asked the whole, it left twice the padding
    # between neighbours, texels the charts could have had
    charts, padding = squares(16, 0.05), 4
    packed = pack(charts, np.ones(16), SIZE, padding, rotate=False)
    chart = charts.corner_chart
    moved = np.einsum("kij,kj->ki", packed.linear[chart], charts.corner_uvs) + packed.offset[chart]
    texels, labels = chart_texels(moved[charts.corner_faces], charts.face_chart(), SIZE)
    assert padding_violations(texels, labels, SIZE, padding) == 0
    assert padding_violations(texels, labels, SIZE, 2 * padding) > 0  # neighbours closer


def test_a_chart_with_a_sliver_face_packs_as_itself_not_as_its_box():
    # a scan's finest faces are under float32's epsilon in UV area (here 5e-8), which xatlas
    # ignores as degenerate: the corner only they use would be left out, the chart boxed
    uvs = np.array([[0, 0], [0.1, 0], [0.1, 0.1], [0, 0.1], [0.05, -1e-6]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 4, 1]])
    packed = pack(Charts(faces, uvs, np.zeros(5, np.int64), 1), np.ones(1), 64, 2, rotate=False)
    assert not packed.boxed[0]
    moved = uvs @ packed.linear[0].T + packed.offset[0]
    assert moved.min() >= 0 and moved.max() <= 1


def test_densities_above_the_bisections_answer_are_tried(monkeypatch):
    # xatlas's placement is a heuristic: here charts fit below half the all-texels density and
    # again between 55 and 60 % of it; the bisection alone would stop just under half
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    charts = Charts(np.array([[0, 1, 2], [0, 2, 3]]), uvs, np.zeros(4, np.int64), 1)
    every_texel = 32.0  # size / sqrt(area): the search's upper end

    def place(charts, scales, size, tpu, padding, rotate, boxes, cap=None, aligned=False):
        fits = tpu < 0.5 * every_texel or 0.55 * every_texel <= tpu < 0.6 * every_texel
        found = packing.Packed(np.eye(2)[None] * tpu / size, np.zeros((1, 2)), tpu, boxes)
        return (found if fits else None), boxes

    monkeypatch.setattr(packing, "_place", place)
    packed = pack(charts, np.ones(1), 32, 1, rotate=False)
    assert 0.55 * every_texel <= packed.texels_per_unit < 0.6 * every_texel


def square_chart() -> Charts:
    """One chart: the unit square, two faces."""
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)
    return Charts(np.array([[0, 1, 2], [0, 2, 3]]), uvs, np.zeros(4, np.int64), 1)


def placing(tried: list[float], fits):
    """A stand-in for ``packing._place`` that records each density tried and packs (as a
    plain scale) where ``fits(density)``."""

    def place(charts, scales, size, tpu, padding, rotate, boxes, cap=None, aligned=False):
        tried.append(tpu)
        found = packing.Packed(np.eye(2)[None] * tpu / size, np.zeros((1, 2)), tpu, boxes)
        return (found if fits(tpu) else None), boxes

    return place


def test_the_density_search_stops_once_its_bracket_is_narrow(monkeypatch):
    # charts fit below half the all-texels density (32): the bisection between 1/16 of it and
    # it narrows to SEARCH_RATIO in 9 looks (ln 16 / 2^9 < ln 1.01 < ln 16 / 2^8), then the
    # probes above
    tried = []
    monkeypatch.setattr(packing, "_place", placing(tried, lambda tpu: tpu < 16.0))
    packed = pack(square_chart(), np.ones(1), 32, 1, rotate=False)
    assert tried[0] == 8.0  # the bracket's middle first
    bisection = tried[: -len(packing.PROBES)]
    assert len(bisection) == 9
    assert 16.0 / packing.SEARCH_RATIO <= packed.texels_per_unit < 16.0


def test_the_search_gives_up_where_its_sparsest_density_does_not_fit(monkeypatch):
    tried = []
    monkeypatch.setattr(packing, "_place", placing(tried, lambda tpu: False))
    with pytest.raises(PackingError, match="do not fit"):
        pack(square_chart(), np.ones(1), 32, 1, rotate=False, sparsest=12.0)
    assert tried == [pytest.approx((12.0 * 32) ** 0.5), 12.0]  # no bisection of failures


def sized_placing(tried: list[tuple[int, float]], fits):
    """As :func:`placing`, recording ``(atlas size, density)`` and packing where
    ``fits(size, density)``."""

    def place(charts, scales, size, tpu, padding, rotate, boxes, cap=None, aligned=False):
        tried.append((size, tpu))
        found = packing.Packed(np.eye(2)[None] * tpu / size, np.zeros((1, 2)), tpu, boxes)
        return (found if fits(size, tpu) else None), boxes

    return place


def test_a_large_atlas_is_searched_coarse_then_climbs_at_full_size(monkeypatch):
    # the unit square fits up to 45 % of the all-texels density in the half-size atlas and up
    # to 47 % at full size: the coarse search aims (no probes, a wider bracket), the full size
    # climbs from just above its answer in CLIMB steps while they fit
    tried = []
    limit = {512: 0.45, 1024: 0.47}
    fits = sized_placing(tried, lambda size, tpu: tpu < limit[size] * size)
    monkeypatch.setattr(packing, "_place", fits)
    packed = pack(square_chart(), np.ones(1), 1024, 4, rotate=False)
    coarse = [tpu for size, tpu in tried if size == 512]
    full = [tpu for size, tpu in tried if size == 1024]
    assert tried == [(512, tpu) for tpu in coarse] + [(1024, tpu) for tpu in full]
    assert coarse[0] == 512 / 4 and len(coarse) == 7  # then ln 4 / 2^6 < ln 1.04 < ln 4 / 2^5
    answer = max(tpu for tpu in coarse if tpu < 0.45 * 512) * 2
    assert 0.45 * 1024 / packing.COARSE_RATIO <= answer < 0.45 * 1024
    assert full == pytest.approx([answer * 1.03 ** (n + 1) for n in range(len(full))])
    assert len(full) <= 3  # 45 % to 47 % is under two climbs
    assert 0.47 * 1024 / packing.CLIMB <= packed.texels_per_unit < 0.47 * 1024


def test_where_the_coarse_answer_overshoots_the_full_size_tries_just_below_it(monkeypatch):
    tried = []
    limit = {512: 0.45, 1024: 0.44}  # the full size fits less: 3 % above does not fit
    monkeypatch.setattr(packing, "_place", sized_placing(tried, lambda s, t: t < limit[s] * s))
    packed = pack(square_chart(), np.ones(1), 1024, 4, rotate=False)
    full = [tpu for size, tpu in tried if size == 1024]
    answer = full[0] / packing.REFINE_STEPS[0]
    assert full == pytest.approx([answer * step for step in packing.REFINE_STEPS[: len(full)]])
    assert packed.texels_per_unit == pytest.approx(full[-1]) and full[-1] < 0.44 * 1024


def test_where_the_coarse_answer_misleads_the_full_size_is_searched_from_scratch(monkeypatch):
    tried = []
    limit = {512: 0.45, 1024: 0.3}  # nothing within REFINE_STEPS of the coarse answer fits
    monkeypatch.setattr(packing, "_place", sized_placing(tried, lambda s, t: t < limit[s] * s))
    packed = pack(square_chart(), np.ones(1), 1024, 4, rotate=False)
    assert 0.3 * 1024 / packing.SEARCH_RATIO <= packed.texels_per_unit < 0.3 * 1024


def test_where_the_coarse_search_finds_nothing_the_full_size_climbs_from_sparsest(
    monkeypatch,
):
    # the least density worth packing, 300, does not fit the half-size atlas (coarse 150 when
    # it fits below 0.1 * 512); at full size it fits below 0.33 * 1024 = 338: one look at
    # 300, then CLIMB steps up to COARSE_SPAN * 300 = 330
    tried = []
    limit = {512: 0.1, 1024: 0.33}
    monkeypatch.setattr(packing, "_place", sized_placing(tried, lambda s, t: t < limit[s] * s))
    packed = pack(square_chart(), np.ones(1), 1024, 4, rotate=False, sparsest=300.0)
    coarse = [tpu for size, tpu in tried if size == 512]
    full = [tpu for size, tpu in tried if size == 1024]
    assert coarse == pytest.approx([(150.0 * 512) ** 0.5, 150.0])  # then it gives up
    assert full == pytest.approx([300.0 * 1.03**n for n in range(4)])
    assert packed.texels_per_unit == pytest.approx(300.0 * 1.03**3)
    tried.clear()
    limit[1024] = 0.25  # nor at full size: refused after one look there
    with pytest.raises(PackingError, match="least density worth packing"):
        pack(square_chart(), np.ones(1), 1024, 4, rotate=False, sparsest=300.0)
    assert [tpu for size, tpu in tried if size == 1024] == [300.0]


def test_a_least_density_above_filling_every_texel_is_refused_without_a_packing(monkeypatch):
    tried = []
    monkeypatch.setattr(packing, "_place", placing(tried, lambda tpu: True))
    with pytest.raises(PackingError, match="least density worth packing"):
        pack(square_chart(), np.ones(1), 32, 1, rotate=False, sparsest=33.0)  # fills at 32
    assert tried == []


def test_the_packing_search_stops_at_its_deadline(monkeypatch):
    # past the deadline no density is tried: the densest found so far packs; none: refused
    charts = square_chart()
    tried = []
    # fits below half the all-texels density, 32
    monkeypatch.setattr(packing, "_place", placing(tried, lambda tpu: tpu < 16.0))
    budget = Budget(TickingClock(), 0.0, 3.5)  # one second a look at the clock
    packed = pack(charts, np.ones(1), 32, 1, rotate=False, budget=budget)
    assert tried == pytest.approx([8.0, 16.0, 8.0 * 2**0.5])  # three looks before 3.5 s
    assert packed.texels_per_unit == pytest.approx(8.0 * 2**0.5)
    tried.clear()
    with pytest.raises(PackingError, match="time budget"):
        pack(charts, np.ones(1), 32, 1, rotate=False, budget=Budget(TickingClock(), 0.0, 0.5))
    assert tried == []


def test_the_cut_is_not_planned_where_it_would_end_past_the_deadline(monkeypatch):
    ribbon = ribbon_mesh(quads=16)  # cut where there is time (above)
    every_face = [torch.arange(len(ribbon.faces))]
    clock = ManualClock()
    plan_charts = atlas_module.plan_charts

    def slow_plan(*args, **kwargs):  # the whole plan takes 600 s
        planned = plan_charts(*args, **kwargs)
        clock.advance(600.0)
        return planned

    monkeypatch.setattr(atlas_module, "plan_charts", slow_plan)
    budget = Budget(clock, 0.0, 1000.0)
    atlas = repack(ribbon, [(SIZE, SIZE)], every_face, 256, budget=budget)
    assert atlas.facts.charts_cut == 1 and not atlas.facts.cut
    assert atlas.facts.cut_skipped == "the time budget left no time to plan the cut"
    assert atlas.facts.k_cut is None and atlas.facts.k == atlas.facts.k_whole


def test_normal_mapped_charts_never_turn_or_mirror():
    mesh = cube_mesh()
    normal = np.full((128, 128, 3), (128, 128, 255), np.uint8)
    mesh.materials[0] = replace(mesh.materials[0], maps={"normalTexture": normal})
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [40, 10, 20, 10, 5, 10]), 256)
    assert (atlas.linear[:, 0, 1] == 0).all() and (atlas.linear[:, 0, 0] > 0).all()
    assert (atlas.linear[:, 1, 1] > 0).all() and not atlas.mirrored.any()


def test_materials_keep_their_layout_with_the_reason():
    mesh = cube_mesh()
    textures = mesh.materials[0].base_color_texture
    transformed = {"normalTexture": {"extensions": {"KHR_texture_transform": {}}}}
    mesh.materials = [
        Material("moved", textures),
        Material("transformed", textures.copy(), properties=transformed,
                 maps={"normalTexture": np.zeros((8, 8, 3), np.uint8)}),
        Material("wide", np.zeros((8, 16, 3), np.uint8)),
    ]  # fmt: skip
    mesh.face_material = np.arange(len(mesh.faces)) // 4  # two charts each
    sizes = [(SIZE, SIZE), (SIZE, SIZE), (4, 8)]
    groups, kept = layout_groups(mesh, sizes, chart_labels(mesh))
    assert groups == [[0]]
    assert kept == {
        1: "normalTexture has a KHR_texture_transform",
        2: "its texture is not square (8x4)",
    }


def identity_layout(mesh) -> ChartMaps:
    """The mesh's charts, each mapped to where it is."""
    count = int(chart_labels(mesh).max()) + 1
    return ChartMaps(
        mesh.corner_uvs(),
        chart_labels(mesh),
        np.tile(np.eye(2), (count, 1, 1)),
        np.zeros((count, 2)),
    )


def test_bake_into_the_same_layout_reproduces_the_texture_gutters_included():
    mesh = cube_mesh(texture_size=64)
    texture = mesh.materials[0].base_color_texture
    baked, covered = bake(texture, COLOR, identity_layout(mesh), 64)
    assert 0 < covered.sum() < covered.size  # the cube's atlas has gutters
    np.testing.assert_array_equal(baked, texture)  # they read the original, as the charts do


def test_an_oversampled_colour_bake_is_the_lanczos_baseline_rounded_once():
    mesh = cube_mesh(texture_size=64)
    texture = mesh.materials[0].base_color_texture
    baked, _ = bake(texture, COLOR, identity_layout(mesh), 32, oversample=2)
    exact = resize_float(texture.astype(np.float32) / 255, (32, 32), Image.Resampling.LANCZOS)
    np.testing.assert_array_equal(baked, np.round(np.clip(exact, 0, 1) * 255).astype(np.uint8))


def test_bake_follows_each_chart_to_its_new_place():
    mesh = cube_mesh(texture_size=64)
    texture = mesh.materials[0].base_color_texture
    atlas = repack(mesh, [(64, 64)], footprint_ids(mesh, [10] * 6), 256)
    layout = ChartMaps(atlas.uvs, atlas.chart_of_face, atlas.linear, atlas.offset)
    baked, covered = bake(texture, COLOR, layout, 64)
    # a texel centre of the new map reads the original where its chart's map sends it back
    rows, cols = np.nonzero(covered)
    row, col = rows[len(rows) // 2], cols[len(cols) // 2]
    point = np.array([(col + 0.5) / 64, 1 - (row + 0.5) / 64])
    texels, labels = chart_texels(atlas.uvs, atlas.chart_of_face, 64)
    chart = labels[texels == row * 64 + col][0]
    old = np.linalg.solve(atlas.linear[chart], point - atlas.offset[chart])
    assert atlas.scales[chart] >= 1.0  # magnified: the nearest original texels, bilinear
    source = texture[int((1 - old[1]) * 64), int(old[0] * 64)].astype(int)
    assert np.abs(baked[row, col].astype(int) - source).max() <= 64


def test_a_bake_read_in_pieces_is_the_bake_read_at_once(monkeypatch):
    import geoscaler.uv.bake as bake_module

    mesh = cube_mesh(texture_size=64)
    texture = mesh.materials[0].base_color_texture
    atlas = repack(mesh, [(64, 64)], footprint_ids(mesh, [10] * 6), 256)
    layout = ChartMaps(atlas.uvs, atlas.chart_of_face, atlas.linear, atlas.offset)
    whole, _ = bake(texture, COLOR, layout, 64, oversample=2)
    monkeypatch.setattr(bake_module, "BAKE_SAMPLES", 1000)  # 17 pieces of the 128 x 128 samples
    pieces, _ = bake(texture, COLOR, layout, 64, oversample=2)
    np.testing.assert_array_equal(pieces, whole)


def test_normals_bake_as_unit_vectors_and_data_per_channel():
    vectors = np.array([[[0.6, 0.0, 0.8]]], np.float32)
    pixels = np.round((vectors + 1) / 2 * 255).astype(np.uint8)
    decoded = decode(pixels, NORMAL)
    np.testing.assert_allclose(decoded.numpy(), vectors, atol=1.01 / 255)  # 8-bit steps
    shortened = torch.tensor([[[0.3, 0.0, 0.4]]])
    np.testing.assert_array_equal(encode(shortened, NORMAL), pixels)  # renormalised
    data = np.array([[[10, 200]]], np.uint8)
    np.testing.assert_array_equal(encode(decode(data, DATA), DATA), data)


@pytest.mark.parametrize(("kind", "channels"), [(COLOR, 4), (COLOR, 3), (NORMAL, 3), (DATA, 2)])
def test_a_map_bakes_from_its_8bit_chain_with_the_bits_of_its_float_chain(kind, channels):
    pixels = np.random.default_rng(11).integers(0, 256, (48, 40, channels), dtype=np.uint8)
    values = torch.from_numpy(pixels.astype(np.float32) / 255.0)  # each class's formula
    if kind == COLOR:
        values[..., :3] = srgb_to_linear(values[..., :3])  # an alpha stays linear
    elif kind == NORMAL:
        values = values * 2.0 - 1.0
    assert torch.equal(decode(pixels, kind), values)
    generator = torch.Generator().manual_seed(12)
    u, v = torch.rand(2, 3000, generator=generator)
    scale = 2.0 ** (torch.rand(3000, generator=generator) * 12 - 8)
    zero = torch.zeros(3000)
    footprint = UVFootprint(u, v, scale, zero, zero, scale)
    encoded = EncodedMipTexture(pixels, decoding=decoding(kind, channels))
    assert torch.equal(encoded.sample(footprint), MipTexture(values).sample(footprint))


def test_a_relaid_renderer_sees_the_same_views_and_references():
    mesh = cube_mesh()
    renderer = Renderer(mesh, "cpu")
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256)
    relaid = renderer.relaid(atlas.uvs, {})
    cameras = validation_cameras()[:3]
    original, moved = ViewSet(renderer, cameras), ViewSet(relaid, cameras)
    for view in range(3):
        reference, foreground = original.reference(view)
        moved_reference, moved_foreground = moved.reference(view)
        assert torch.equal(foreground, moved_foreground)  # view for view
        assert torch.equal(reference, moved_reference)  # the original on its own UVs
    assert relaid.view_memo and len(relaid.view_memo) == 3


def test_a_chart_longer_than_asked_is_halved_into_connected_pieces():
    ribbon = ribbon_mesh(quads=16)  # 32 faces: quad q is faces q and 16 + q
    charts = chart_labels(ribbon)
    pieces = cut_charts(ribbon, charts, np.array([0.3]))  # 0.9 long: halved twice
    np.testing.assert_array_equal(pieces, np.tile(np.arange(16) // 4, 2))
    np.testing.assert_array_equal(cut_charts(ribbon, charts, np.array([np.inf])), charts)
    quad = ribbon_mesh(quads=1)  # 0.9 long: cut along its diagonal, the one inner edge
    np.testing.assert_array_equal(cut_charts(quad, np.zeros(2, np.int64), np.array([0.5])), [0, 1])
    triangle = replace(quad, faces=quad.faces[:1], face_material=quad.face_material[:1])
    np.testing.assert_array_equal(cut_charts(triangle, np.zeros(1, np.int64), np.array([0.1])), [0])


def test_a_chart_spanning_the_atlas_is_cut_where_the_pieces_pack_denser():
    ribbon = ribbon_mesh(quads=16)
    every_face = [torch.arange(len(ribbon.faces))]
    atlas = repack(ribbon, [(SIZE, SIZE)], every_face, 256)
    assert atlas.facts.charts_cut == 1 and atlas.facts.cut
    assert atlas.facts.k == atlas.facts.k_cut >= CUT_GAIN * atlas.facts.k_whole
    pieces = atlas.facts.charts
    assert pieces > 1
    assert atlas.facts.vertices_added == 2 * (pieces - 1)  # two vertices on each cut
    assert atlas_problems(ribbon, atlas) == []
    cut = ribbon.with_uvs(atlas.uvs)
    np.testing.assert_array_equal(chart_labels(cut), atlas.chart_of_face)  # pieces as charts
    np.testing.assert_array_equal(cut.positions[cut.faces], ribbon.positions[ribbon.faces])


def test_the_cut_is_searched_no_sparser_than_it_would_be_taken(monkeypatch):
    ribbon = ribbon_mesh(quads=16)
    every_face = [torch.arange(len(ribbon.faces))]
    gains = []
    plan_charts = atlas_module.plan_charts

    def recording_plan(*args, **kwargs):
        gains.append(kwargs["terms"].least_gain)
        return plan_charts(*args, **kwargs)

    monkeypatch.setattr(atlas_module, "plan_charts", recording_plan)
    atlas = repack(ribbon, [(SIZE, SIZE)], every_face, 256)
    assert gains == [LEAST_GAIN, pytest.approx(CUT_GAIN * atlas.facts.k_whole)]
    # where no packing of the pieces is that dense, the cut is refused and says why
    monkeypatch.setattr(atlas_module, "CUT_GAIN", 100.0)
    refused = repack(ribbon, [(SIZE, SIZE)], every_face, 256)
    assert not refused.facts.cut and refused.facts.k_cut is None
    assert refused.facts.k == refused.facts.k_whole == atlas.facts.k_whole
    assert refused.facts.cut_skipped.startswith("the pieces' layout was refused: the UV charts")


def test_only_the_layout_taken_is_checked_by_the_guards(monkeypatch):
    ribbon = ribbon_mesh(quads=16)  # cut and taken (above): the whole plan goes unchecked
    every_face = [torch.arange(len(ribbon.faces))]
    checked = []
    group_problems = atlas_module.group_problems

    def recording_problems(mesh, atlas, group):
        checked.append(atlas.facts.charts if atlas.facts else None)
        return group_problems(mesh, atlas, group)

    monkeypatch.setattr(atlas_module, "group_problems", recording_problems)
    atlas = repack(ribbon, [(SIZE, SIZE)], every_face, 256)
    assert atlas.facts.cut and checked == [atlas.facts.charts]


def test_a_group_that_breaks_a_guard_keeps_its_layout_and_says_which(monkeypatch):
    mesh = cube_mesh()
    monkeypatch.setattr(atlas_module, "group_problems", lambda *args: ["2 charts overlap"])
    atlas = repack(mesh, [(SIZE, SIZE)], footprint_ids(mesh, [10] * 6), 256)
    assert not atlas.moved and atlas.groups == []
    assert atlas.kept == {"cube": "the new UV layout broke a guard: 2 charts overlap"}
    np.testing.assert_array_equal(atlas.uvs, mesh.corner_uvs())


def test_a_long_chart_is_cut_to_half_the_atlas_where_it_would_fill_every_texel():
    # the ribbon's one chart, 0.9 x 0.1 UV units, fills the atlas at 1 / sqrt(0.09) new UV
    # units per old one: half the atlas is 0.5 * 0.3 = 0.15 old units, however densely the
    # whole chart happened to pack
    ribbon = ribbon_mesh(quads=16)
    charts = chart_labels(ribbon)
    every_face = [torch.arange(len(ribbon.faces))]
    whole = plan_charts(ribbon, [(SIZE, SIZE)], charts, every_face, 256, None)
    assert cut_lengths(ribbon, whole, charts) == pytest.approx([0.15], rel=1e-5)
    sparser = replace(whole, planned=whole.planned * 0.9)
    assert cut_lengths(ribbon, sparser, charts) == pytest.approx([0.15], rel=1e-5)


def test_each_charts_affine_map_and_largest_residual_are_fitted_at_once():
    # chart 0 moved by a quarter turn and scale 2, chart 1 by a shift, one of its points off
    old = np.array([[0, 0], [1, 0], [0, 1], [0.2, 0.3], [5, 5], [6, 5], [5, 7]], np.float64)
    chart = np.array([0, 0, 0, 0, 1, 1, 1])
    turn = np.array([[0.0, -2.0], [2.0, 0.0]])
    new = np.r_[old[:4] @ turn.T + [3, 4], old[4:] + [-1, 0.5]]
    new[6] += [0.0, 0.03]
    linear, offset, residual = packing._fit(old, chart, new, 2)
    np.testing.assert_allclose(linear[0], turn, atol=1e-12)
    np.testing.assert_allclose(offset[0], [3, 4], atol=1e-12)
    assert residual[0] < 1e-12
    assert 0.0 < residual[1] <= 0.03
