"""Rendering as the protocol defines it: cameras, the rasteriser, the one texture sampler (and its
8-bit reference chain), the renderer, the paper's soft rasteriser, cached view sets and the
metrics."""
