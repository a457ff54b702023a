"""The Khronos glTF Validator (npm package gltf-validator, run by node) for the export tests."""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VALIDATOR = ROOT / "tests" / "validators"


def validate(path):
    """The Khronos glTF Validator's report on ``path`` (node + the npm package gltf-validator)."""
    if shutil.which("node") is None or not (VALIDATOR / "node_modules" / "gltf-validator").is_dir():
        pytest.fail("the glTF Validator is not installed: run scripts/setup-env test (npm ci in tests/validators)")
    run = subprocess.run(["node", str(VALIDATOR / "validate_gltf.js"), str(path)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def assert_clean(report):
    issues = report["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, json.dumps(issues["messages"][:10], indent=1)
