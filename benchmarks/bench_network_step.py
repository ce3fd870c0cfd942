"""Seconds of one network step (forward and backward, rendering excluded), per preset.

Usage: python benchmarks/bench_network_step.py MESH cpu,paper   (variant full, scale 4)
"""

import sys
import time
from dataclasses import replace

import torch

from geoscaler.io import load_mesh
from geoscaler.methods.network import PRESETS, build_network


def main(mesh_path: str, presets: str) -> None:
    mesh = load_mesh(mesh_path)
    for preset in presets.split(","):
        config = replace(PRESETS[preset].network, variant="full")
        model = build_network(mesh, 4, config, torch.device("cpu"))
        seconds = []
        for _ in range(3):
            start = time.perf_counter()
            (texture,), uvs = model.candidate()
            (texture.square().mean() + uvs.square().mean()).backward()
            seconds.append(round(time.perf_counter() - start, 2))
        size = tuple(model.inputs[0].shape[1:])
        print(f"{preset}: input {size}, output {tuple(texture.shape[:2])}, step s {seconds}")


if __name__ == "__main__":
    main(*sys.argv[1:3])
