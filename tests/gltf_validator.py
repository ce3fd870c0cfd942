"""The Khronos glTF-Validator (the npm package ``gltf-validator`` that ``make validator``
installs into ``.tools/``), run by node on many files at once: for the tests and the
benchmarks."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = ROOT / ".tools" / "node_modules" / "gltf-validator"
SCRIPT = """
const fs = require("fs"), path = require("path");
const validator = require(process.env.GLTF_VALIDATOR);
(async () => {
  const out = {};
  for (const file of process.argv.slice(2)) {
    const report = await validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {
      uri: path.basename(file), maxIssues: 0, writeTimestamp: false,
      externalResourceFunction: (uri) => new Promise((resolve, reject) => fs.readFile(
        path.resolve(path.dirname(file), decodeURIComponent(uri)),
        (error, data) => error ? reject(error.toString()) : resolve(new Uint8Array(data)))),
    });
    out[file] = {errors: report.issues.numErrors, warnings: report.issues.numWarnings,
                 messages: report.issues.messages};
  }
  process.stdout.write(JSON.stringify({version: validator.version(), reports: out}));
})().catch((error) => { console.error(String(error)); process.exit(1); });
"""


class ValidatorMissing(Exception):
    """node or the validator package is not installed (the message says which and what to do)."""


def validate(files: list[Path]) -> tuple[str, dict[str, dict]]:
    """The validator's version and its report of each file (``errors``, ``warnings``,
    ``messages``), by path as given; one node process for all."""
    node = shutil.which("node")
    if node is None:
        raise ValidatorMissing("node is not installed, so the glTF-Validator (npm) cannot run")
    if not (VALIDATOR / "package.json").is_file():
        raise ValidatorMissing(
            f"the glTF-Validator is not installed in {VALIDATOR.parent}: run `make validator` "
            "(make test does it)"
        )
    with tempfile.TemporaryDirectory() as folder:
        script = Path(folder) / "validate.js"
        script.write_text(SCRIPT)
        done = subprocess.run(
            [node, str(script), *map(str, files)],
            capture_output=True,
            text=True,
            env={"GLTF_VALIDATOR": str(VALIDATOR), "PATH": ""},
            timeout=600,
            check=False,
        )
    if done.returncode != 0:
        raise RuntimeError(f"the glTF-Validator failed: {done.stderr}")
    result = json.loads(done.stdout)
    return result["version"], {str(path): result["reports"][str(path)] for path in files}
