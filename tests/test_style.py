"""The whole tree is `ruff format`ted at line length 100 and passes `ruff check` (issue 27).

Run by the test command so that CI holds every commit to it; each check is shown failing on a
planted file.
"""

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUFF = [sys.executable, "-m", "ruff"]


def ruff(*args, cwd=ROOT):
    return subprocess.run([*RUFF, *args], cwd=cwd, capture_output=True, text=True)


def test_line_length_is_100():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert config["tool"]["ruff"]["line-length"] == 100


def test_the_tree_is_formatted_and_lint_clean():
    done = ruff("format", "--check", ".")
    assert done.returncode == 0, f"run `ruff format .`:\n{done.stdout}{done.stderr}"
    done = ruff("check", "--quiet", ".")
    assert done.returncode == 0, f"run `ruff check .`:\n{done.stdout}{done.stderr}"


def test_the_checks_can_fail(tmp_path):
    config = ("--config", str(ROOT / "pyproject.toml"))
    (tmp_path / "messy.py").write_text("x = {  'a':1 }\n")
    assert ruff("format", *config, "--check", ".", cwd=tmp_path).returncode == 1
    (tmp_path / "messy.py").write_text(f'x = "{"a" * 120}"\n')
    done = ruff("check", *config, "--quiet", ".", cwd=tmp_path)
    assert done.returncode == 1 and "E501" in done.stdout, done.stdout
