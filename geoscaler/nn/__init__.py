"""The GeoScaler network's ``nn.Module``s: encoder and decoder, GeoCoding, UVWarper, the
network with its ablation variants, and the VGG-19 perceptual term.

Modules, each testable alone: :mod:`~geoscaler.nn.convolutional`, :mod:`~geoscaler.nn.geocoding`,
:mod:`~geoscaler.nn.uvwarper`, :mod:`~geoscaler.nn.network` (variants) and
:mod:`~geoscaler.nn.perceptual`. What they read of the mesh is built in
:mod:`geoscaler.uv.uvmaps`; the method that trains them per mesh is
:mod:`geoscaler.methods.network`.
"""
