"""GeoScaler: geometry- and rendering-aware downsampling of 3D mesh textures."""

from geoscaler.errors import GeoscalerError
from geoscaler.protocol import PROTOCOL

__version__ = "0.1.0"

__all__ = ["GeoscalerError", "PROTOCOL", "__version__"]
