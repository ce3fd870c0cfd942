"""The protocol cameras: fixed validation views, seeded training views, GL matrices."""

import math

import numpy as np
import pytest

from geoscaler.render.cameras import (
    Camera,
    fibonacci_directions,
    sample_training_cameras,
    validation_cameras,
)


def test_validation_set_is_the_protocol_fibonacci_sphere():
    cameras = validation_cameras()
    assert len(cameras) == 60
    assert all(c.distance == 2.4 for c in cameras)
    z7 = 1 - 15 / 60
    a7 = 7 * math.pi * (3 - math.sqrt(5))
    r7 = math.sqrt(1 - z7 * z7)
    np.testing.assert_allclose(cameras[7].direction, [r7 * math.cos(a7), r7 * math.sin(a7), z7])
    np.testing.assert_allclose(np.linalg.norm(fibonacci_directions(), axis=1), 1.0)


def test_robustness_sets_share_directions():
    near, far = validation_cameras(1.5), validation_cameras(4.0)
    assert [c.direction for c in near] == [c.direction for c in far]
    assert {c.distance for c in near} == {1.5} and {c.distance for c in far} == {4.0}
    with pytest.raises(ValueError):
        validation_cameras(0.0)


def test_training_cameras_are_seeded_and_in_range():
    first = sample_training_cameras(50, seed=3)
    assert first == sample_training_cameras(50, seed=3)
    assert first != sample_training_cameras(50, seed=4)
    distances = np.array([c.distance for c in first])
    assert distances.min() >= 1.8 and distances.max() <= 3.0
    np.testing.assert_allclose(np.linalg.norm([c.direction for c in first], axis=1), 1.0)


def test_training_cameras_take_several_ranges_in_turn():
    cameras = sample_training_cameras(40, seed=3, distances=((2.0, 2.5), (3.5, 4.0)))
    distances = np.array([c.distance for c in cameras])
    assert ((distances[0::2] >= 2.0) & (distances[0::2] <= 2.5)).all()
    assert ((distances[1::2] >= 3.5) & (distances[1::2] <= 4.0)).all()
    # the directions do not depend on the ranges
    single = sample_training_cameras(40, seed=3, distances=(2.0, 2.5))
    assert [c.direction for c in cameras] == [c.direction for c in single]


def test_view_matrix_puts_eye_at_origin_looking_down_minus_z():
    camera = Camera((0.6, 0.0, 0.8), 2.0)
    view = camera.view_matrix()
    np.testing.assert_allclose(view @ np.append(camera.eye, 1), [0, 0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(view @ [0, 0, 0, 1], [0, 0, -2, 1], atol=1e-12)
    right, up, back = camera.axes()
    np.testing.assert_allclose(np.cross(right, up), back, atol=1e-12)
    assert right[1] == pytest.approx(0.0) and up[1] > 0  # world +Y is up on screen


def test_near_pole_views_use_plus_z_as_up():
    camera = Camera((0.0, 1.0, 0.0), 2.4)
    right, up, _ = camera.axes()
    np.testing.assert_allclose(right, [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(up, [0, 0, 1], atol=1e-12)


def test_projection_maps_clip_planes_and_field_of_view():
    camera = Camera((0.0, 0.0, 1.0), 3.0)
    near, far = camera.near_far()
    assert (near, far) == (1.0, 5.0)
    projection = camera.projection_matrix()

    def ndc(point):
        clip = projection @ np.append(point, 1.0)
        return clip[:3] / clip[3]

    assert ndc([0, 0, -near])[2] == pytest.approx(-1.0)
    assert ndc([0, 0, -far])[2] == pytest.approx(1.0)
    top = 2.0 * math.tan(math.radians(22.5))
    assert ndc([0, top, -2.0])[1] == pytest.approx(1.0)
    assert Camera((0.0, 0.0, 1.0), 1.0).near_far()[0] == 0.001
