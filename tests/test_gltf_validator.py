"""What GeoScaler writes passes the Khronos glTF-Validator with 0 errors.

The validator is the npm package ``gltf-validator`` that ``make test`` installs into ``.tools/``
(pinned in the Makefile). One node process validates every file: the built-in demo asset, the
hand-made asset of ``io_assets`` (TANGENT, COLOR_0, TEXCOORD_1, ``texCoord: 1``,
``KHR_texture_transform``, ``KHR_materials_clearcoat``, a shared image, JPEG and PNG), a
triangle whose base colour has a ``KHR_texture_transform`` (mirror, turn, offset), each as
loaded and with its textures changed, as .gltf and .glb, WebP once, and the Poly Haven sofa and
stool and the WebP cat from ../shared/data when they are there. Skipped only without node.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA_DIR, ONE_VIEW
from gltf_validator import ValidatorMissing, validate
from io_assets import rich_gltf
from mesh_support import write_gltf

from geoscaler.cli import main
from geoscaler.io import load_mesh, save_mesh
from geoscaler.mesh import TexturedMesh
from geoscaler.procedural import demo_mesh

DEVELOPMENT = {
    "sofa": "ph_sofa_03/sofa_03_1k.gltf",
    "stool": "ph_painted_wooden_stool/painted_wooden_stool_1k.gltf",
    "cat": "pc_egyptian_cat/cat.glb",
}


def halved(mesh: TexturedMesh) -> TexturedMesh:
    """Every texture replaced by its every other texel (sharing kept): re-encoded on save."""
    return mesh.with_images({id(p): np.ascontiguousarray(p[::2, ::2]) for p, _ in mesh.images()})


def outputs(folder: Path) -> dict[str, Path]:
    """Every file to validate, by case name; written into ``folder``."""
    cases: dict[str, tuple[TexturedMesh, str | None]] = {
        "demo": (demo_mesh(subdivisions=6, texture_size=64), None),
    }
    cases["demo-webp"] = (cases["demo"][0], "webp")
    rich = load_mesh(rich_gltf(folder / "rich-input"))
    cases.update({"rich": (rich, None), "rich-halved": (halved(rich), None)})
    cases["rich-webp"] = (rich, "webp")
    transform = {"offset": [0.25, -0.5], "rotation": 0.5, "scale": [-1.0, 1.5]}
    material = {"pbrMetallicRoughness": {"baseColorTexture": {
        "index": 0, "extensions": {"KHR_texture_transform": transform}}}}  # fmt: skip
    uvs = np.float32([[0.1, 0.9], [0.7, 0.8], [0.2, 0.15]])
    cases["transformed"] = (load_mesh(write_gltf(folder / "transformed-input", uvs,
                                                 material=material)), None)  # fmt: skip
    for name, entry in DEVELOPMENT.items():
        if (DATA_DIR / entry).is_file():
            mesh = load_mesh(DATA_DIR / entry)
            cases.update({name: (mesh, None), f"{name}-halved": (halved(mesh), None)})
    files = {"rich-input.gltf": folder / "rich-input" / "rich.gltf"}
    files.update(downsampled(folder, cases["demo"][0]))
    for name, (mesh, image_format) in cases.items():
        for suffix in (".gltf", ".glb"):
            (folder / name / suffix[1:]).mkdir(parents=True)
            path = folder / name / suffix[1:] / f"{name}{suffix}"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                files[f"{name}{suffix}"] = save_mesh(mesh, path, image_format=image_format)[-1]
    return files


def downsampled(folder: Path, demo: TexturedMesh) -> dict[str, Path]:
    """What ``geoscaler downsample`` writes (Lanczos, 2x, every map) for the demo asset and the
    sofa, as .gltf and .glb."""
    save_mesh(demo, folder / "demo-input.glb")
    inputs = {"demo": folder / "demo-input.glb", "sofa": DATA_DIR / DEVELOPMENT["sofa"]}
    files = {}
    for name, source in inputs.items():
        for suffix in (".gltf", ".glb") if source.is_file() else ():
            out = folder / f"downsampled-{name}" / f"{name}{suffix}"
            out.parent.mkdir(exist_ok=True)
            argv = [
                "downsample",
                str(source),
                "-o",
                str(out),
                "--scale",
                "2",
                "--method",
                "lanczos",
            ]
            assert main(argv, evaluation=ONE_VIEW) == 0
            files[f"downsampled-{name}{suffix}"] = out
    return files


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, dict]:
    """The validator's report of every output, one node process for all."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed, so the Khronos glTF-Validator (npm) cannot run")
    files = outputs(tmp_path_factory.mktemp("validated"))
    try:
        version, by_path = validate(list(files.values()))
    except ValidatorMissing as missing:
        pytest.fail(str(missing))
    print(f"gltf-validator {version}")
    return {name: by_path[str(path)] for name, path in files.items()}


CASES = ["rich-input.gltf"] + [
    f"{name}{suffix}"
    for name in ["demo", "demo-webp", "rich", "rich-halved", "rich-webp", "transformed"]
    + ["downsampled-demo"]
    + ["downsampled-sofa"]
    + [f"{n}{h}" for n in DEVELOPMENT for h in ("", "-halved")]
    for suffix in (".gltf", ".glb")
]


@pytest.mark.parametrize("case", CASES)
def test_output_has_no_validator_errors(reports: dict[str, dict], case: str):
    if case not in reports:
        pytest.skip(f"{case}: its development mesh is not in {DATA_DIR}")
    report = reports[case]
    errors = [m for m in report["messages"] if m["severity"] == 0]
    shown = "\n".join(f"{m['code']} at {m.get('pointer', '?')}: {m['message']}" for m in errors)
    assert report["errors"] == 0, f"{case}: {report['errors']} error(s)\n{shown}"
