"""Node kinds share contracts (``nodes/contracts/``), not each other's private modules.

Walks every import statement of every module under ``nodes/`` (top-level and inside functions,
absolute and relative) and fails when a module of one kind imports any module of another kind,
public or private: what kinds share lives in ``nodes/contracts/``.
"""

from __future__ import annotations

import ast
from pathlib import Path

NODES = Path(__file__).resolve().parents[1] / "nodes"
SHARED = {"contracts"}  # public to every kind


def _module_parts(path: Path) -> list[str]:
    rel = path.relative_to(NODES.parent).with_suffix("")
    parts = list(rel.parts)
    return parts[:-1] if parts[-1] == "__init__" else parts


def _imported_modules(path: Path) -> list[tuple[int, list[str]]]:
    """``(line, dotted module parts)`` of every import in a file, relative imports resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    here = _module_parts(path)
    package = here if path.name == "__init__.py" else here[:-1]
    found = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            found += [(n.lineno, a.name.split(".")) for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            base = package[: len(package) - (n.level - 1)] if n.level else []
            mod = base + (n.module.split(".") if n.module else [])
            found.append((n.lineno, mod))
            # ``from nodes.sources import _render`` imports a module too
            found += [(n.lineno, [*mod, a.name]) for a in n.names]
    return found


def cross_kind_imports() -> list[str]:
    bad = []
    for path in sorted(NODES.rglob("*.py")):
        parts = _module_parts(path)
        kind = parts[1] if len(parts) > 1 else None
        for line, mod in _imported_modules(path):
            if len(mod) < 2 or mod[0] != "nodes" or mod[1] == kind or mod[1] in SHARED:
                continue
            entry = (
                f"{path.relative_to(NODES.parent).as_posix()}:{line} imports {'.'.join(mod[:3])}"
            )
            if entry not in bad and not any(b.startswith(entry + ".") for b in bad):
                bad.append(entry)
    return [b for b in bad if not any(o != b and o.startswith(b + ".") for o in bad)]


def test_no_kind_imports_another_kinds_module():
    bad = cross_kind_imports()
    assert not bad, (
        "move what these share into nodes/contracts/ (see docs/artifacts.md):\n  "
        + "\n  ".join(bad)
    )


def test_the_walk_sees_cross_kind_imports(tmp_path):
    # The check itself can fail: planted cross-kind imports, private and public, are reported.
    fake = tmp_path / "nodes"
    (fake / "ik").mkdir(parents=True)
    (fake / "actuators").mkdir()
    (fake / "ik" / "_model.py").write_text("X = 1\n")
    (fake / "actuators" / "a.py").write_text(
        "def f():\n    from nodes.ik._model import X\n    return X\n"
    )
    (fake / "actuators" / "b.py").write_text("from nodes.ik import _model\nfrom ._own import Y\n")
    (fake / "actuators" / "c.py").write_text(
        "from nodes.ik.arm import arm_model\nfrom nodes.contracts import x\n"
    )
    globals()["NODES"], old = fake, NODES
    try:
        bad = cross_kind_imports()
    finally:
        globals()["NODES"] = old
    assert bad == [
        "nodes/actuators/a.py:2 imports nodes.ik._model",
        "nodes/actuators/b.py:1 imports nodes.ik._model",
        "nodes/actuators/c.py:1 imports nodes.ik.arm",
    ]


def test_a_malformed_record_fails_the_node_that_made_it_not_the_next(tmp_path):
    # (a plugin segmenter returning {"segmentation": "oops"} was reported as "disparity: ...
    # disparity input is not a Segmentation record": the node that read it was blamed)
    import textwrap

    from stereograph.core.runner import run_pipeline

    plug = tmp_path / "badloc.py"
    plug.write_text(
        textwrap.dedent("""\
        from stereograph.core.api import In, Out, node

        @node("bad.items", outputs={"n": Out("any", collection=True)})
        def items(params):
            return {"n": {f"p{i}": i for i in range(3)}}

        @node("bad.locate", inputs={"n": In("any")}, outputs={"location": Out("Location")})
        def locate(params, n):
            return {"location": {"found": True, "x_cm": 1.0} if n == 0 else "oops"}
        """)
    )
    nodes = [
        "items: {type: bad.items}",
        "locate: {type: bad.locate, inputs: {n: items.n}}",
        "report: {type: report.accuracy, params: {figure: false, split: all},"
        " inputs: {locations: locate.location}}",
    ]
    p = tmp_path / "p.yaml"
    p.write_text(f"name: p\nplugins: [{plug}]\nnodes:\n" + "".join(f"  {n}\n" for n in nodes))
    r = run_pipeline(p, cache_dir=tmp_path / "c", out_dir=tmp_path / "o")
    rep = r.reports["locate"]
    assert rep.status == "partial" and rep.items_failed == 2, (rep.status, rep.error)
    assert (
        "bad.locate: its output 'location' is not a Location: got a str, not a record (a dict)"
        in rep.error
    )
    assert r.reports["report"].status == "ran" and r.outputs("report", "metrics")["n_lost"] == 2


def test_an_image_output_must_be_an_array_of_rows_and_columns():
    # (an Out("Image") returning a dict or None was saved as picture.json, silently)
    import numpy as np

    import nodes  # noqa: F401  (registers the checks)
    from stereograph.core.checks import ARTIFACT_CHECKS

    check = ARTIFACT_CHECKS["Image"]
    assert (
        check(np.zeros((4, 5), np.uint8)) is None and check(np.zeros((4, 5, 3), np.float32)) is None
    )
    assert "not an image" in check({"left": 1}) and "shape (4, 5, 2)" in check(np.zeros((4, 5, 2)))
    assert "not an image" in check([[0, 1], [2, 3]])


def test_every_node_function_is_found_by_name_in_a_worker_process():
    """A worker process (--workers, --dask, compare --workers) gets a node's function by reference:
    its module's attribute of its name must be it. (segmenter.watershed and segmenter.slic were
    named after their method while their modules' attributes of that name were scikit-image's
    functions: every run with workers failed "Can't pickle <function watershed>".)"""
    import pickle

    from stereograph.core import registry

    bad = []
    for name in registry.names():
        try:
            pickle.dumps(registry.get(name).fn)
        except (pickle.PicklingError, AttributeError, TypeError) as e:
            bad.append(f"{name}: {e}")
    assert bad == []

    def planted():  # a function its module does not hold under its name: what the check must catch
        return None

    planted.__module__, planted.__qualname__ = "nodes.segmenters.color", "no_such_attribute"
    try:
        pickle.dumps(planted)
    except (pickle.PicklingError, AttributeError):
        pass
    else:
        raise AssertionError(
            "a function its module does not hold pickled: the check above cannot fail"
        )
