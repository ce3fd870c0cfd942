"""The assets of a library: finding them under IN_DIR, their outputs under OUT_DIR, and
whether an earlier batch finished them (``--resume``)."""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from geoscaler.io import find_assets as find_io_assets
from geoscaler.report.documents import json_safe
from geoscaler.resize.sizes import TEXTURE_CLASSES

STAGING_PREFIX = ".geoscaler-batch-"
"""Staging folders: an asset's files are written there, then renamed into place."""
REPORT_SUFFIX = ".report.json"


@dataclass(frozen=True)
class Asset:
    """One asset of the library: ``name`` is the input's path under IN_DIR (the summary's key),
    ``problem`` why it cannot run, when known before running it."""

    name: str
    path: Path
    output: Path
    problem: str | None = None

    @property
    def report(self) -> Path:
        return self.output.with_name(self.output.stem + REPORT_SUFFIX)

    @property
    def staging_prefix(self) -> str:
        """Prefix of its staging folders: a hash of its name, so no other asset's matches."""
        return f"{STAGING_PREFIX}{hashlib.sha1(self.name.encode()).hexdigest()[:16]}-"


def find_assets(in_dir: Path, skip: Sequence[Path] = ()) -> list[tuple[str, Path, str | None]]:
    """``(name, path, problem)`` of every asset under ``in_dir`` (:func:`geoscaler.io.find_assets`:
    a folder's ``meta.json`` entry, else every mesh file; hidden folders and ``skip``, OUT_DIR
    inside IN_DIR, not searched), in sorted order. An entry outside IN_DIR is a problem."""
    root = in_dir.resolve()
    return [
        (found.relative, found.path, None if found.path.resolve().is_relative_to(root) else
         "its folder's meta.json names an entry outside IN_DIR")
        for found in find_io_assets(in_dir, skip)
    ]  # fmt: skip


def plan_assets(in_dir: Path, out_dir: Path, output_format: str | None = None) -> list[Asset]:
    """The assets under ``in_dir`` and their outputs under ``out_dir`` (same relative path;
    suffix ``output_format`` or the input's). Two assets whose outputs would share a folder and
    a stem (``a.obj`` and ``a.glb`` with ``--format gltf``: both write ``a.gltf``, ``a.bin`` and
    their images) cannot both be written: the second in sorted order gets a problem."""
    assets, claimed = [], {}
    for name, path, problem in find_assets(in_dir, [out_dir]):
        suffix = f".{output_format}" if output_format else path.suffix.lower()
        output = out_dir / Path(name).with_suffix(suffix)
        key = (output.parent.as_posix(), output.stem.casefold())
        if problem is None and key in claimed:
            problem = (
                f"its outputs ({output.stem}.*) would overwrite those of {claimed[key]}, in the "
                "same output folder; rename one of the two"
            )
        claimed.setdefault(key, name)
        assets.append(Asset(name, path, output, problem))
    return assets


def resume_key(settings: dict[str, Any], output_format: str | None) -> dict[str, Any]:
    """What must match for ``--resume`` to take an earlier output: everything the job was asked
    to do (not the device it ran on), as JSON."""
    options = settings["options"]
    key = {
        "method": settings["method"],
        "sizes": {kind: settings["sizes"].rule(kind).label for kind in TEXTURE_CLASSES},
        "image_format": settings["image_format"],
        "protocol": settings.get("protocol"),
        "format": output_format,
        "seed": options.seed,
        "steps": options.steps,
        "time_budget": options.time_budget,
        "settings": options.settings,
    }
    return json.loads(json.dumps(json_safe(key), default=str, sort_keys=True))


def completed(asset: Asset, key: dict[str, Any]) -> dict[str, Any] | None:
    """The report of ``asset`` when an earlier batch finished it with the same ``key`` and its
    outputs and report are all there and newer than every file it was made from; else None."""
    try:
        document = json.loads(asset.report.read_text(encoding="utf-8"))
        record = document["batch"]
        if record["settings"] != key:
            return None
        inputs = [asset.path.parent / p for p in record["inputs"]]
        outputs = [asset.output.parent / p for p in record["outputs"]]
        newest = max(p.stat().st_mtime_ns for p in [asset.path, *inputs])
        if asset.output not in outputs:
            return None
        if any(p.stat().st_mtime_ns <= newest for p in [*outputs, asset.report]):
            return None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return document


def sweep(asset: Asset) -> None:
    """Remove what a worker that died left of ``asset``: its staging folders."""
    for staging in asset.output.parent.glob(asset.staging_prefix + "*"):
        shutil.rmtree(staging, ignore_errors=True)
