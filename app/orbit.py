"""The app's interactive camera: orbit, zoom and pan around the protocol's scene.

It is a thin state over :class:`geoscaler.cameras.Camera` (one camera convention for the whole
project): yaw and pitch give the view direction, ``distance`` the eye distance, and ``pan`` an
image shift in normalised device units applied after the protocol projection.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

from geoscaler.cameras import Camera
from geoscaler.protocol import VALIDATION_DISTANCE

MIN_DISTANCE = 1.1  # just outside the unit sphere that holds the normalised mesh
MAX_DISTANCE = 12.0
PITCH_LIMIT = 89.0


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

    def shift(self, dx: float, dy: float, view_pixels: float) -> None:
        """Pan by a drag of ``(dx, dy)`` pixels in a view ``view_pixels`` wide."""
        x, y = self.pan
        self.pan = (x + 2.0 * dx / view_pixels, y - 2.0 * dy / view_pixels)

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
