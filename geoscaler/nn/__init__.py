"""The GeoScaler network: encoder, GeoCoding, UVWarper, decoder, and the method that trains it.

Modules, each testable alone: :mod:`~geoscaler.nn.geometry` (what the network reads of the
mesh), :mod:`~geoscaler.nn.convolutional`, :mod:`~geoscaler.nn.geocoding`,
:mod:`~geoscaler.nn.uvwarper`, :mod:`~geoscaler.nn.network` (variants),
:mod:`~geoscaler.nn.perceptual` (VGG-19 term) and :mod:`~geoscaler.nn.method` (presets).
"""
