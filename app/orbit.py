"""The app's interactive camera: orbit, zoom and pan around the protocol's scene.

It is a thin state over :class:`geoscaler.render.cameras.Camera` (one camera convention for the
whole project): yaw and pitch give the view direction, ``distance`` the eye distance, and ``pan`` an
image shift in normalised device units applied after the protocol projection.

The app's views need not be square: :func:`view_scale` keeps the protocol's field of view across
a view's longer side and narrows the shorter one. :meth:`Orbit.frame` moves the eye (and pans)
so that the mesh fills the view. The protocol scene (the mesh normalised into the unit sphere)
already fits a square view at the protocol's distance -- the sphere's outline spans 1.1 times
the view -- so framing the bounding sphere would change nothing: what leaves a wide mesh small
is a square view, where it is a thin band. Framing fits the mesh's own outline, seen from the
camera, to the view's shape instead.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from geoscaler.protocol import FOV_Y_DEGREES, VALIDATION_DISTANCE
from geoscaler.render.cameras import Camera

MIN_DISTANCE = 1.1  # just outside the unit sphere that holds the normalised mesh
MAX_DISTANCE = 12.0
PITCH_LIMIT = 89.0
FILL = 0.92
"""The share of a view's half-width (or half-height) that a framed mesh reaches."""


def view_scale(width: float, height: float) -> tuple[float, float]:
    """``(x, y)`` scale of clip coordinates for a ``width`` x ``height`` view: the protocol's
    field of view spans the longer side, the shorter side sees less (1, 1 for a square). (Across
    the shorter side, a view 4 times wider than high would see 118 degrees across: a fisheye.)"""
    return max(1.0, height / width), max(1.0, width / height)


@dataclass
class Orbit:
    """Camera state in the units people drag in.

    Attributes:
        yaw, pitch: degrees; yaw 0, pitch 0 looks at the mesh from +Z, pitch > 0 from above.
        distance: eye distance in normalised scene units (2.4 is the protocol's).
        pan: ``(x, y)`` image shift in normalised device units.
    """

    yaw: float = 30.0
    pitch: float = 20.0
    distance: float = VALIDATION_DISTANCE
    pan: tuple[float, float] = (0.0, 0.0)

    def camera(self) -> Camera:
        """The protocol camera at this orbit position."""
        yaw, pitch = math.radians(self.yaw), math.radians(self.pitch)
        direction = (
            math.cos(pitch) * math.sin(yaw),
            math.sin(pitch),
            math.cos(pitch) * math.cos(yaw),
        )
        return Camera(direction, self.distance)

    def rotate(self, dx: float, dy: float) -> None:
        """Orbit by a mouse drag of ``(dx, dy)`` pixels (0.4 degrees a pixel)."""
        self.yaw = (self.yaw - 0.4 * dx) % 360.0
        self.pitch = min(max(self.pitch + 0.4 * dy, -PITCH_LIMIT), PITCH_LIMIT)

    def zoom(self, wheel: float) -> None:
        """Move the eye 10% closer per wheel notch (negative: farther)."""
        self.distance = min(max(self.distance * 0.9**wheel, MIN_DISTANCE), MAX_DISTANCE)

    def shift(
        self, dx: float, dy: float, view_pixels: float, view_height: float | None = None
    ) -> None:
        """Pan by a drag of ``(dx, dy)`` pixels in a view ``view_pixels`` wide and
        ``view_height`` high (None: square)."""
        x, y = self.pan
        height = view_pixels if view_height is None else view_height
        self.pan = (x + 2.0 * dx / view_pixels, y - 2.0 * dy / height)

    def frame(self, points: np.ndarray, aspect: float) -> None:
        """Frame ``points`` (``(N, 3)``, the normalised mesh) in a view ``aspect`` (width /
        height) wide, seen from this yaw and pitch: the pan centres their outline and the
        distance is the nearest at which it spans :data:`FILL` of the view's width or height.

        A point ``x, y`` across the view and ``z`` towards the eye lands at ``f s x / (D - z)``
        in normalised device units (``f`` the focal length, ``s`` :func:`view_scale`); the
        outline's span shrinks as the eye moves away, so the distance is found by bisection.
        """
        right, up, back = self.camera().axes()
        points = np.asarray(points, np.float64)
        if not len(points):
            return
        focal = 1.0 / math.tan(math.radians(FOV_Y_DEGREES) / 2)
        scale_x, scale_y = view_scale(aspect, 1.0)
        across = np.stack([points @ right * scale_x, points @ up * scale_y]) * focal
        towards = points @ back

        def outline(distance: float) -> tuple[np.ndarray, np.ndarray]:
            projected = across / (distance - towards)
            return projected.min(axis=1), projected.max(axis=1)

        def fits(distance: float) -> bool:
            low, high = outline(distance)
            return bool((high - low).max() <= 2 * FILL)

        near, far = MIN_DISTANCE, MAX_DISTANCE
        if fits(near):
            far = near
        elif not fits(far):
            near = far
        while far - near > 1e-4:
            middle = (near + far) / 2
            near, far = (near, middle) if fits(middle) else (middle, far)
        low, high = outline(far)
        self.distance = far
        self.pan = (float(-(low[0] + high[0]) / 2), float(-(low[1] + high[1]) / 2))

    def outline(self, points: np.ndarray) -> tuple[float, float]:
        """``(width, height)`` of ``points`` seen from this yaw and pitch (parallel projection,
        scene units): the shape a view must have for the mesh to fill it."""
        right, up, _ = self.camera().axes()
        points = np.asarray(points, np.float64)
        if not len(points):
            return 1.0, 1.0
        return (
            max(float(np.ptp(points @ right)), 1e-6),
            max(float(np.ptp(points @ up)), 1e-6),
        )

    def reset(self) -> None:
        """Back to the start view."""
        self.yaw, self.pitch, self.distance, self.pan = Orbit().to_tuple()

    def to_tuple(self) -> tuple[float, float, float, tuple[float, float]]:
        return self.yaw, self.pitch, self.distance, self.pan

    def to_dict(self) -> dict:
        state = asdict(self)
        state["pan"] = list(self.pan)
        return state

    @classmethod
    def from_dict(cls, state: dict) -> Orbit:
        """An orbit from :meth:`to_dict`'s form; raises ValueError/KeyError on bad input."""
        pan = state.get("pan", (0.0, 0.0))
        orbit = cls(
            float(state["yaw"]),
            float(state["pitch"]),
            float(state["distance"]),
            (float(pan[0]), float(pan[1])),
        )
        if not MIN_DISTANCE <= orbit.distance <= MAX_DISTANCE:
            raise ValueError(f"distance {orbit.distance} outside [{MIN_DISTANCE}, {MAX_DISTANCE}]")
        return orbit
