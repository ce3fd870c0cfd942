"""Whole assets: every development mesh downsampled as a user runs it, then measured.

For each mesh and scale: ``geoscaler downsample MESH --scale S -o OUT.glb --report R`` (the
method and budget given here), then from the report: bytes on disk before (every file the
asset was read from) and after, texture memory before and after (4 bytes a texel, every map),
how each map was made; then the Khronos glTF-Validator on every output. Prints a Markdown
table; the worst mesh is named.

    python benchmarks/whole_assets.py ../shared/data --scales 4 8 --method direct \\
        --time-budget 30 --out /tmp/whole_assets
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from gltf_validator import validate  # noqa: E402


def entries(data: Path) -> list[Path]:
    """The entry file of every development mesh (``meta.json``'s ``entry``)."""
    return [m.parent / json.loads(m.read_text())["entry"] for m in sorted(data.glob("*/meta.json"))]


def run(mesh: Path, scale: int, args: argparse.Namespace) -> dict:
    """One downsampling job in its own process; its report, wall seconds added."""
    out = args.out / f"{mesh.parent.name}_x{scale}.glb"
    report = out.with_suffix(".json")
    command = [str(ROOT / ".venv" / "bin" / "geoscaler"), "downsample", str(mesh), "-o", str(out)]
    command += ["--scale", str(scale), "--method", args.method, "--report", str(report), "--force"]
    if args.time_budget is not None:
        command += ["--time-budget", str(args.time_budget)]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return {"mesh": mesh.parent.name, "scale": scale, "error": done.stderr.strip()[-300:]}
    document = json.loads(report.read_text())
    document.update(mesh=mesh.parent.name, scale=scale, wall=time.perf_counter() - started)
    document["path"] = out
    return document


def row(document: dict, validation: dict) -> str:
    if "error" in document:
        return f"| {document['mesh']} | {document['scale']} | failed: {document['error']} |"
    totals = document["totals"]
    memory = totals["memory_before"] / totals["memory_after"]
    disk = totals["bytes_after"] / totals["bytes_before"]
    method_row = document["results"][0]
    maps = ", ".join(sorted({m["class"] for m in document["maps"]}))
    report = validation[str(document["path"])]
    return (
        f"| {document['mesh']} | {document['scale']} | {len(document['maps'])} ({maps}) | "
        f"{totals['bytes_before'] / 1e6:.2f} | {totals['bytes_after'] / 1e6:.2f} | {disk:.1%} | "
        f"{memory:.2f} | {method_row['gain_db']:+.2f} | {document['details'].get('shipped', '')} "
        f"| {report['errors']} / {report['warnings']} | {document['wall']:.0f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="folder of development meshes")
    parser.add_argument("--scales", type=int, nargs="+", default=[4, 8])
    parser.add_argument("--method", default="direct")
    parser.add_argument("--time-budget", type=float, default=None)
    parser.add_argument("--out", type=Path, default=Path("/tmp/whole_assets"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    documents = [run(mesh, scale, args) for mesh in entries(args.data) for scale in args.scales]
    done = [d for d in documents if "error" not in d]
    version, validation = validate([d["path"] for d in done])
    print(f"glTF-Validator {version}; method {args.method}, budget {args.time_budget} s\n")
    print(
        "| mesh | scale | maps (classes) | MB before | MB after | file after/before | "
        "texture memory before/after | gain dB (Q) | shipped | validator errors / warnings "
        "| wall s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for document in documents:
        print(row(document, validation))
    if done:
        worst = max(done, key=lambda d: d["totals"]["bytes_after"] / d["totals"]["bytes_before"])
        ratio = worst["totals"]["bytes_after"] / worst["totals"]["bytes_before"]
        print(
            f"\nlargest output relative to its input: {worst['mesh']} x{worst['scale']} {ratio:.1%}"
        )


if __name__ == "__main__":
    main()
