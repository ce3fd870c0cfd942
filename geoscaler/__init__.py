"""GeoScaler: geometry- and rendering-aware downsampling of 3D mesh textures."""

from geoscaler.errors import GeoscalerError

__version__ = "0.1.0"
PROTOCOL = 1

__all__ = ["GeoscalerError", "PROTOCOL", "__version__"]
