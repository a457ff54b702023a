"""constraints.txt pins every dependency, and the environment the tests run in was installed by it.

The alignment's results follow numpy's, scipy's and numba's floating point, so an install that
resolves newer versions gives other numbers: scripts/setup-env and docker/Dockerfile install with
``-c constraints.txt``.
"""

import re
import tomllib
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def canonical(name):
    return re.sub(r"[-_.]+", "-", name).lower()


def pins():
    found = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, sep, version = line.partition("==")
            assert sep and version, f"constraints.txt: {line!r} is not NAME==VERSION"
            found[canonical(name)] = version
    return found


def declared():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = project["dependencies"] + [r for extra in project["optional-dependencies"].values() for r in extra]
    return {canonical(re.match(r"[A-Za-z0-9_.\-]+", r).group(0)) for r in requirements}


def test_every_declared_dependency_is_pinned():
    missing = sorted(declared() - set(pins()))
    assert not missing, f"constraints.txt does not pin {missing}: regenerate it (its header says how)"


def test_the_installed_versions_are_the_pinned_ones():
    wrong = {}
    for name, version in pins().items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue  # a pin for another platform's or an optional package
        if installed != version:
            wrong[name] = (installed, version)
    assert not wrong, f"installed != pinned (scripts/setup-env installs with -c constraints.txt): {wrong}"


def test_the_installers_use_the_constraints():
    assert "-c constraints.txt" in (ROOT / "scripts" / "setup-env").read_text()
    dockerfile = (ROOT / "docker" / "Dockerfile").read_text()
    assert "COPY pyproject.toml README.md constraints.txt" in dockerfile
    assert "pip install -c constraints.txt ." in dockerfile  # the dependencies' layer
