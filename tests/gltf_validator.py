"""Run the Khronos glTF validator (npm package ``gltf-validator``) from the tests.

The package is pinned in ``tests/tools/package.json``; on first use it is installed into
``tests/tools/node_modules`` (git-ignored) with ``npm install``, so a fresh CI machine with
node + npm needs nothing else. Tests skip only when npm (or node) is absent.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

TOOLS = Path(__file__).parent / "tools"
SCRIPT = TOOLS / "validate_gltf.js"


def ensure_validator() -> None:
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm not installed: cannot run the Khronos glTF validator")
    if (TOOLS / "node_modules" / "gltf-validator" / "package.json").is_file():
        return
    proc = subprocess.run(
        ["npm", "install", "--no-audit", "--no-fund", "--prefix", str(TOOLS)],
        cwd=TOOLS, capture_output=True, text=True, timeout=600,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"npm install gltf-validator failed:\n{proc.stdout}\n{proc.stderr}")


def validate(path) -> dict:
    """The validator's JSON report for ``path`` (``report['issues']['numErrors']`` etc.)."""
    ensure_validator()
    proc = subprocess.run(["node", str(SCRIPT), str(path)], capture_output=True, text=True, timeout=600)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"glTF validator failed to run on {path}: {proc.stderr}")
    return json.loads(proc.stdout)


def problems(report: dict, max_severity: int = 1) -> list[str]:
    """Messages at or above a severity (0 error, 1 warning, 2 info, 3 hint), one line each."""
    return [f"{m['code']} {m.get('pointer', '')}: {m['message']}"
            for m in report["issues"]["messages"] if m["severity"] <= max_severity]
