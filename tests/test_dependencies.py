"""pyproject's dependencies match what the code imports, both ways (issue 14 item 6).

Every third-party package that ``stereograph/`` or ``nodes/`` imports is declared (core or an
extra), and every core dependency is imported somewhere: ``pip install -e .`` pulls nothing the
code does not use. Import names differ from distribution names; the map below says how.
"""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# import name -> distribution name, where they differ
DIST_OF_IMPORT = {
    "cv2": "opencv-contrib-python-headless",
    "yaml": "pyyaml",
    "PIL": "pillow",
    "skimage": "scikit-image",
    "sklearn": "scikit-learn",
    "dynamixel_sdk": "dynamixel-sdk",
    "serial": "pyserial",
    "distributed": "dask",  # the 'dask' extra: dask[distributed]
}
LOCAL = {"stereograph", "nodes", "simbench"}


def _dist_name(requirement: str) -> str:
    return re.split(r"[\s\[<>=!~;]", requirement.strip(), maxsplit=1)[0].lower().replace("_", "-")


def _declared() -> tuple[set[str], set[str]]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = {_dist_name(r) for r in project["dependencies"]}
    extras = {
        _dist_name(r)
        for name, reqs in project.get("optional-dependencies", {}).items()
        if name != "dev"
        for r in reqs
    }
    return core, extras


def _imported() -> dict[str, set[str]]:
    """Top-level third-party import names -> files importing them (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for package in LOCAL:
        for f in sorted((ROOT / package).rglob("*.py")):
            for n in ast.walk(ast.parse(f.read_text(encoding="utf-8"), str(f))):
                if isinstance(n, ast.Import):
                    names = [a.name for a in n.names]
                elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                    names = [n.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in LOCAL:
                        found.setdefault(top, set()).add(str(f.relative_to(ROOT)))
    return found


def test_every_imported_package_is_declared():
    core, extras = _declared()
    missing = {
        name: sorted(files)
        for name, files in _imported().items()
        if DIST_OF_IMPORT.get(name, name).lower() not in core | extras
    }
    assert not missing, f"imported but not declared in pyproject.toml: {missing}"


@pytest.mark.slow
def test_every_core_dependency_is_imported():
    core, _ = _declared()
    used = {DIST_OF_IMPORT.get(name, name).lower() for name in _imported()}
    unused = core - used
    assert not unused, (
        "declared in pyproject.toml but imported nowhere in stereograph/ or nodes/: "
        f"{sorted(unused)}"
    )


def test_the_check_sees_known_imports():
    # the walk must find what the code is known to import, or both tests above pass vacuously
    imported = _imported()
    assert {"cv2", "numpy", "yaml", "pydantic", "scipy", "filelock"} <= set(imported)
    assert "nodes/compensators/disparity_curve.py" in imported["scipy"]


def test_license_is_an_spdx_expression():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "Apache-2.0"
