"""Test-suite settings.

The suite's pipelines import the project's own toy plugins (tests/plugins/); the command line
refuses plugins unless told (docs/security.md), so the suite says so once here, as a user who
trusts these files would with ``STEREOGRAPH_ALLOW_PLUGINS=1``. tests/test_engine_security.py
removes it to check the refusal.
"""

from __future__ import annotations

import pytest


@pytest.fixture(autouse=True)
def _trust_the_suites_plugins(monkeypatch):
    monkeypatch.setenv("STEREOGRAPH_ALLOW_PLUGINS", "1")


def pytest_configure(config):
    """Compile the project's modules once, before the workers start, as an installed package has
    them: where PYTHONDONTWRITEBYTECODE is set (this sandbox, some CI images) every worker and every
    ``python -m stereograph`` the suite starts would compile them from source again."""
    if hasattr(config, "workerinput"):  # (a worker: the controller did it)
        return
    import compileall
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for folder in ("stereograph", "nodes", "simbench", "tests/plugins"):
        compileall.compile_dir(root / folder, quiet=2)
