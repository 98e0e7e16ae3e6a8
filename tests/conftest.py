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
