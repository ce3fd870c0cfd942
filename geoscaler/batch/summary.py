"""The summary of a batch: ``summary.csv``, ``summary.json`` and ``summary.md``."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from geoscaler.io.atomic import write_files
from geoscaler.report.documents import dumps, json_safe

from .assets import Asset
from .worker import DONE, FAILED, SKIPPED, AssetResult

SUMMARY_FILES = ("summary.csv", "summary.json", "summary.md")
COLUMNS = [
    "asset", "status", "output", "method", "shipped", "gain_db", "memory_before",
    "memory_after", "bytes_before", "bytes_after", "seconds", "device", "host", "error",
]  # fmt: skip
"""Columns of the summary: ``gain_db`` is the shipped result's PSNR-fg gain over bicubic on
the job's validation views; memory is texture memory (4 bytes a texel), bytes are on disk."""


def summary_row(asset: Asset, result: AssetResult, out_dir: Path) -> dict[str, Any]:
    """One asset in the summary (keys :data:`COLUMNS`), from its report where it has one."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(asset=asset.name, status=result.status, error=result.error)
    if result.status in (DONE, FAILED):
        row["seconds"] = round(result.seconds, 3)
    document = result.document
    if document is not None:
        own = next((r for r in document["results"] if r["method"] == document["method"]), {})
        record = document.get("batch", {})
        row.update(document.get("totals", {}))
        row.update(
            output=asset.output.relative_to(out_dir).as_posix(),
            method=document["method"],
            shipped=own.get("shipped"),
            gain_db=own.get("gain_db"),
            device=document.get("device"),
            host=record.get("host"),
        )
        if result.status == SKIPPED:
            row["seconds"] = record.get("seconds")
    return {key: row[key] for key in COLUMNS}


def total_row(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The summary's total line: counts by status, mean gain, sums of memory, bytes, seconds."""
    counts: dict[str, int] = {}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    gains = [row["gain_db"] for row in rows if row["gain_db"] is not None]
    total: dict[str, Any] = dict.fromkeys(COLUMNS)
    total["asset"] = "total"
    total["status"] = ", ".join(f"{n} {status}" for status, n in counts.items())
    total["gain_db"] = round(sum(gains) / len(gains), 4) if gains else None
    for key in ("memory_before", "memory_after", "bytes_before", "bytes_after", "seconds"):
        total[key] = sum(row[key] for row in rows if row[key] is not None)
    total["seconds"] = round(total["seconds"], 3)
    return total


def _size(count: int | None) -> str:
    if count is None:
        return ""
    return f"{count / 1e6:.2f} MB" if count >= 100_000 else f"{count / 1e3:.1f} kB"


def _sizes(sizes: dict[str, Any]) -> str:
    """``{"color": 4, "normal": "x2, <= 1024"}`` -> ``"color x4; normal x2, <= 1024"``."""
    return "; ".join(
        f"{kind} {f'x{rule}' if isinstance(rule, int) else rule}" for kind, rule in sizes.items()
    )


def markdown_summary(document: dict[str, Any]) -> str:
    """``summary.md``: what ran, then one table row per asset and the total, then the errors."""
    run = document["run"]
    lines = [
        f"# geoscaler batch: {document['in_dir']} -> {document['out_dir']}",
        "",
        f"method {run['settings']['method']}, sizes {_sizes(run['settings']['sizes'])}; engine "
        f"{run['engine']} ({run['workers']}); wall {run['wall_seconds']:.0f} s, "
        f"{run['assets_per_hour']:.1f} assets per hour (assets this run did / wall time)",
        "",
        "| asset | status | gain over bicubic (dB) | texture memory | on disk | seconds | device |",
        "| --- | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for row in [*document["assets"], document["total"]]:
        gain = "" if row["gain_db"] is None else f"{row['gain_db']:+.2f}"
        memory = f"{_size(row['memory_before'])} -> {_size(row['memory_after'])}"
        disk = f"{_size(row['bytes_before'])} -> {_size(row['bytes_after'])}"
        seconds = "" if row["seconds"] is None else f"{row['seconds']:.1f}"
        memory, disk = ("", "") if row["memory_before"] is None else (memory, disk)
        cells = [row["asset"], row["status"], gain, memory, disk, seconds, row["device"] or ""]
        if row is document["total"]:
            cells = [f"**{cell}**" if cell else "" for cell in cells]
        lines.append("| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |")
    errors = [row for row in document["assets"] if row["error"]]
    if errors:
        lines += ["", "Failed:", ""] + [f"- {row['asset']}: {row['error']}" for row in errors]
    return "\n".join(lines) + "\n"


def write_summary(out_dir: Path, document: dict[str, Any]) -> list[Path]:
    """``summary.csv`` (the total last), ``summary.json`` and ``summary.md``, atomically as a
    set: where one cannot be written (no space left...), WriteError names it and none is."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows([*document["assets"], document["total"]])
    texts = [buffer.getvalue(), dumps(json_safe(document)) + "\n", markdown_summary(document)]
    contents = {name: text.encode("utf-8") for name, text in zip(SUMMARY_FILES, texts, strict=True)}
    return write_files(out_dir, contents)  # all three, or none (the earlier ones kept)
