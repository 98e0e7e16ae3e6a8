"""Shape checks of artifact types, registered by the node library and run by the engine on every
output (:func:`stereograph.core.api.artifact_check`). A module of its own, with no imports, so that
registering them costs nothing at start-up (``stereograph nodes`` imports the node packages)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["ARTIFACT_CHECKS", "artifact_check"]

#: Artifact type name -> ``check(value) -> None | why``, registered with :func:`artifact_check`.
ARTIFACT_CHECKS: dict[str, Callable[[Any], str | None]] = {}


def artifact_check(
    type_name: str,
) -> Callable[[Callable[[Any], str | None]], Callable[[Any], str | None]]:
    """Register a check of an artifact type's shape, run on every output declared of that type.

    ``check(value)`` returns None when the value has the type's shape, else a few words on why not.
    A value of the wrong shape then fails the node that made it (naming the output and its type)
    instead of the next node, which would only see a malformed input. Register cheap checks (the
    keys a record must have), once, where the type's contract is defined.
    """

    def register(check: Callable[[Any], str | None]) -> Callable[[Any], str | None]:
        ARTIFACT_CHECKS[type_name] = check
        return check

    return register
