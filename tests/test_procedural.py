"""The built-in demo asset (`geoscaler.procedural.scan_mesh`): laid out as a scan's atlas is.

Exact expectations on the asset `geoscaler demo` builds: its chart count, UV coverage, empty
texture, one edge-connected unfolded piece per chart, and detail at several scales; and the same
arguments give the same arrays.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from geoscaler.procedural import SCAN_COVERAGE, SCAN_DILATION, scan_mesh
from geoscaler.uv.packing import signed_areas
from geoscaler.uv.uvmaps import chart_labels, uv_coverage


@pytest.fixture(scope="module")
def pebble():
    return scan_mesh()


def test_the_demo_asset_has_tens_of_charts_on_a_mostly_empty_atlas(pebble):
    pebble.validate()
    assert len(pebble.faces) == 20 * 4**5 and len(pebble.positions) == 11_445
    assert pebble.materials[0].base_color_texture.shape == (2048, 2048, 3)
    assert int(chart_labels(pebble).max()) + 1 == 31
    assert SCAN_COVERAGE == 0.2
    assert uv_coverage(pebble) == pytest.approx(0.2, abs=1e-3)
    assert uv_coverage(pebble, resolution=2048) == pytest.approx(0.2, abs=2e-4)
    # charts never overlap: their UV areas add up to the coverage
    assert np.abs(signed_areas(pebble.uvs, pebble.faces)).sum() == pytest.approx(0.2, rel=1e-6)
    assert pebble.uvs.min() > 0 and pebble.uvs.max() < 1
    texture = pebble.materials[0].base_color_texture
    empty = texture.max(axis=2) == 0
    assert empty.mean() == pytest.approx(0.718, abs=1e-3)  # black beyond the dilation


def test_every_chart_is_one_unfolded_edge_connected_piece(pebble):
    assert (signed_areas(pebble.uvs, pebble.faces) > 0).all()
    charts = chart_labels(pebble)
    edges = np.sort(pebble.vertex_to_point[pebble.faces][:, [[0, 1], [1, 2], [2, 0]]], axis=2)
    _, edge = np.unique(edges.reshape(-1, 2), axis=0, return_inverse=True)
    order = np.argsort(edge, kind="stable")
    face = np.repeat(np.arange(len(pebble.faces)), 3)[order]
    a, b = face[0::2], face[1::2]
    assert (edge[order][0::2] == edge[order][1::2]).all()  # closed: two faces an edge
    inside = charts[a] == charts[b]
    count = len(pebble.faces)
    graph = coo_matrix((np.ones(inside.sum()), (a[inside], b[inside])), shape=(count, count))
    assert connected_components(graph, directed=False)[0] == int(charts.max()) + 1


def test_detail_at_several_scales(pebble):
    """Inside the charts, bicubic down and up again loses about 5.5 dB per halving of the size
    (the development scans lose about 5 dB on Q): a 4x smaller texture with 1.41 times the
    texels per side on the charts (what a repack with half the atlas empty gives) holds about
    3 dB more, and even 2x loses detail (the grain)."""
    texture = pebble.materials[0].base_color_texture
    inside = ndimage.binary_erosion(texture.max(axis=2) > 0, iterations=SCAN_DILATION + 8)
    image = Image.fromarray(texture)

    def psnr(size: int) -> float:
        small = image.resize((size, size), Image.BICUBIC)
        back = np.asarray(small.resize(image.size, Image.BICUBIC), dtype=np.float64)
        return float(-10 * np.log10(((back - texture)[inside] ** 2).mean() / 255**2))

    by_size = {size: psnr(size) for size in (1024, 724, 512, 256)}
    assert by_size[1024] < 40
    assert 2.5 < by_size[724] - by_size[512] < 3.5
    assert 4.5 < by_size[512] - by_size[256] < 6.5


def test_the_same_arguments_give_the_same_asset():
    first, second = scan_mesh(level=3, texture_size=256), scan_mesh(level=3, texture_size=256)
    for name in ("positions", "faces", "uvs", "normals", "vertex_to_point"):
        assert np.array_equal(getattr(first, name), getattr(second, name)), name
    assert np.array_equal(
        first.materials[0].base_color_texture, second.materials[0].base_color_texture
    )
    other = scan_mesh(level=3, texture_size=256, seed=18)
    assert other.uvs.shape != first.uvs.shape or not np.array_equal(other.uvs, first.uvs)
