"""Cameras of PROTOCOL.md: one convention for the whole project (OpenGL, right-handed).

A camera sits at ``distance * direction`` and looks at the origin (along ``-direction``) with a
45-degree vertical field of view and a square image. Matrices are float64 numpy arrays that map
column vectors (``clip = projection @ view @ [x, y, z, 1]``). In the image, row 0 is the top and
pixel centres lie at half-integers, as GL rasterises.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from geoscaler.protocol import FOV_Y_DEGREES, RANGE_S, VALIDATION_DISTANCE, VIEWS, Evaluation

_POLE_COS = math.cos(math.radians(1.0))


@dataclass(frozen=True)
class Camera:
    """A protocol camera.

    Attributes:
        direction: ``(3,)`` unit vector from the origin towards the eye.
        distance: eye distance from the origin, in normalised scene units.
    """

    direction: tuple[float, float, float]
    distance: float

    @property
    def eye(self) -> np.ndarray:
        """``(3,)`` float64 eye position."""
        return self.distance * np.asarray(self.direction, dtype=np.float64)

    def axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(right, up, back)`` unit vectors of the camera frame; the camera looks along -back."""
        back = np.asarray(self.direction, dtype=np.float64)
        world_up = np.array([0.0, 0.0, 1.0] if abs(back[1]) > _POLE_COS else [0.0, 1.0, 0.0])
        right = np.cross(world_up, back)
        right /= np.linalg.norm(right)
        return right, np.cross(back, right), back

    def view_matrix(self) -> np.ndarray:
        """``(4, 4)`` world-to-eye transform."""
        right, up, back = self.axes()
        rotation = np.stack([right, up, back])
        view = np.eye(4)
        view[:3, :3] = rotation
        view[:3, 3] = -rotation @ self.eye
        return view

    def near_far(self) -> tuple[float, float]:
        """Clip planes: near ``max(0.5 (D - 1), 0.001)``, far ``D + 2``."""
        return max(0.5 * (self.distance - 1.0), 0.001), self.distance + 2.0

    def projection_matrix(self) -> np.ndarray:
        """``(4, 4)`` OpenGL perspective projection (square image)."""
        near, far = self.near_far()
        f = 1.0 / math.tan(math.radians(FOV_Y_DEGREES) / 2)
        return np.array(
            [
                [f, 0.0, 0.0, 0.0],
                [0.0, f, 0.0, 0.0],
                [0.0, 0.0, (far + near) / (near - far), 2 * far * near / (near - far)],
                [0.0, 0.0, -1.0, 0.0],
            ]
        )

    def clip_matrix(self) -> np.ndarray:
        """``(4, 4)`` world-to-clip transform, ``projection @ view``."""
        return self.projection_matrix() @ self.view_matrix()


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def fibonacci_directions(count: int = VIEWS) -> np.ndarray:
    """``(count, 3)`` float64 unit directions of the protocol's Fibonacci sphere, view i = row i."""
    i = np.arange(count, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / count
    azimuth = i * math.pi * (3.0 - math.sqrt(5.0))
    radius = np.sqrt(1.0 - z * z)
    return np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), z], axis=1)


def validation_cameras(distance: float = VALIDATION_DISTANCE) -> list[Camera]:
    """Validation set Q (60 fixed views at 2.4), or the near/far robustness sets by distance."""
    if not distance > 0:
        raise ValueError(f"camera distance must be positive, got {distance}")
    return [Camera(tuple(d), float(distance)) for d in fibonacci_directions()]


def sample_training_cameras(
    count: int,
    seed: int,
    distances: Sequence[float] | Sequence[Sequence[float]] = RANGE_S,
) -> list[Camera]:
    """Range S: directions uniform on the sphere, distance uniform in ``distances``.

    ``distances`` is one ``(nearest, farthest)`` range, or several taken in turn (camera ``i``
    from range ``i`` modulo their count), so that any first cameras of the list mix them.
    The same ``seed`` always gives the same cameras.
    """
    rng = np.random.default_rng(seed)
    directions = _unit(rng.standard_normal((count, 3)))
    ranges = np.atleast_2d(np.asarray(distances, dtype=np.float64))
    chosen = ranges[np.arange(count) % len(ranges)]
    lengths = rng.uniform(chosen[:, 0], chosen[:, 1])
    return [Camera(tuple(d), float(r)) for d, r in zip(directions, lengths, strict=True)]


def spread_order(count: int) -> list[int]:
    """A permutation of ``range(count)`` whose every prefix spreads over a Fibonacci sphere of
    ``count`` views: ``i * step mod count`` with ``step`` the integer coprime to ``count``
    nearest ``0.382 count`` (consecutive picks land far apart in height and azimuth)."""
    target = (3 - math.sqrt(5)) / 2 * count
    steps = sorted(range(1, max(count, 2)), key=lambda k: abs(k - target))
    step = next((k for k in steps if math.gcd(k, count) == 1), 1)
    return [i * step % count for i in range(count)]


def sample_extent(depth: float, samples_per_side: int) -> float:
    """The largest scene size of one screen sample on a surface facing the camera at ``depth``
    (along the view axis), anywhere in the frame: at the frame's corners a sample spans
    ``1 + 2 tan^2(fov / 2)`` times its size at the centre."""
    half = math.tan(math.radians(FOV_Y_DEGREES) / 2)
    return depth * 2 * half / samples_per_side * (1 + 2 * half * half)


def view_set_cameras(distance: float, evaluation: Evaluation) -> list[Camera]:
    """The cameras of the protocol's view set at ``distance`` that ``evaluation`` scores on:
    all 60 (protocol 1) or the views it lists."""
    cameras = validation_cameras(distance)
    return [cameras[i] for i in evaluation.view_indices]
