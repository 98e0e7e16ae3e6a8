"""Fuzzed data files: every reader of a file from elsewhere ends in a result or a NodeError, never
another exception (an "internal error" for the user), whatever the bytes.

Seeds are real files (the shipped live calibration, compensation model and hand-eye; a truth CSV; a
target-point CSV); hypothesis cuts, repeats, overwrites them and swaps numbers for hostile ones
(nan, inf, 0, -1, huge). Bounded here (tests/fuzzing.examples); ``STEREOGRAPH_FUZZ_SCALE=25`` for
the large version. ``FUZZ_REPORT=path`` appends each reader's count and slowest example to that
file.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
import time
from pathlib import Path

import pytest
from fuzzing import examples
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereograph.core.api import NodeError

ROOT = Path(__file__).resolve().parents[1]
LIVE = ROOT / "pipelines" / "live"
pytestmark = pytest.mark.slow

TRUTH_CSV = "id,x_cm,y_cm,z_cm,radius_cm,split\n" + "".join(
    f"p{i:03d},{i * 0.5:.3f},{-i * 0.25:.3f},{30 + i:.3f},2.0,{'train' if i % 2 else 'test'}\n"
    for i in range(12)
)
TARGET_CSV = "id,x_cm,y_cm,z_cm,u_px,v_px\n" + "".join(
    f"t{i},{i % 4 * 2.5},{i // 4 * 2.5},{(i % 3) * 1.0},{100 + 20 * i:.2f},{80 + 11 * i:.2f}\n"
    for i in range(16)
)
HOSTILE = [
    b"nan",
    b".nan",
    b"inf",
    b"-inf",
    b".Inf",
    b"0",
    b"-1",
    b"1e308",
    b"-1e308",
    b"2000000000",
    b"",
    b"[]",
    b"{}",
    b"null",
    b"\x00",
    b"[[[[[[[[",
    b"*a",
    b"&a x",
]
NUMBER = re.compile(rb"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


@st.composite
def mutated(draw, seed: bytes) -> bytes:
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["number", "cut", "repeat", "overwrite", "truncate"]))
        if kind == "number":
            spans = [m.span() for m in NUMBER.finditer(bytes(data))]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data[a:b] = draw(st.sampled_from(HOSTILE))
            continue
        if not data:
            break
        a = draw(st.integers(0, len(data) - 1))
        b = draw(st.integers(a, min(len(data), a + 200)))
        if kind == "cut":
            del data[a:b]
        elif kind == "repeat":
            data[b:b] = data[a:b] * draw(st.integers(1, 50))
        elif kind == "overwrite":
            data[a:b] = draw(st.binary(max_size=40))
        else:
            del data[a:]
    return bytes(data)


def _calibration(path: Path):
    from nodes.calibrators.load import LoadParams, load

    return load(LoadParams(path=str(path)))


def _model(path: Path):
    from nodes.calibrators.load import read_calibration_file
    from nodes.compensators.load import load
    from nodes.contracts.calibration_file import ArtifactLoadParams

    return load(
        ArtifactLoadParams(path=str(path)),
        calibration=read_calibration_file(LIVE / "calibration.yml"),
    )


def _hand_eye(path: Path):
    from nodes.calibrators.load import load_hand_eye, read_calibration_file
    from nodes.contracts.calibration_file import ArtifactLoadParams

    calibration = read_calibration_file(LIVE / "calibration.yml")
    return load_hand_eye(ArtifactLoadParams(path=str(path)), calibration=calibration)


def _truth(path: Path):
    from nodes.sources._truth import read_truth_file

    return read_truth_file(path)


def _targets(path: Path):
    from nodes.sources.target_points import read_target_csv

    return read_target_csv(path, ("",))


READERS = {
    "calibration (OpenCV YAML)": (_calibration, (LIVE / "calibration.yml").read_bytes(), ".yml"),
    "compensation model (JSON)": (_model, (LIVE / "model.json").read_bytes(), ".json"),
    "hand-eye (JSON)": (_hand_eye, (LIVE / "hand_eye.json").read_bytes(), ".json"),
    "truth (CSV)": (_truth, TRUTH_CSV.encode(), ".csv"),
    "target points (CSV)": (_targets, TARGET_CSV.encode(), ".csv"),
}


@pytest.mark.parametrize("name", list(READERS))
# (a NumPy warning fails it, as pyproject's filterwarnings says: the hand-eye check of a file with
# 1e300 in it overflowed)
def test_a_fuzzed_file_is_read_or_refused_in_words(name):
    read, seed, suffix = READERS[name]
    read(_write(seed, suffix))  # the seed itself reads
    stats = {"n": 0, "refused": 0, "slowest_s": 0.0}

    @settings(
        max_examples=examples(150),
        deadline=None,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(data=mutated(seed))
    def check(data):
        path = _write(data, suffix)
        t0 = time.perf_counter()
        try:
            read(path)
        except NodeError:
            stats["refused"] += 1
        finally:
            stats["slowest_s"] = max(stats["slowest_s"], time.perf_counter() - t0)
            stats["n"] += 1
            path.unlink()

    check()
    if os.environ.get("FUZZ_REPORT"):
        with open(os.environ["FUZZ_REPORT"], "a") as f:
            f.write(
                f"{name}: {stats['n']} examples, {stats['refused']} refused with a "
                "NodeError, 0 other "
                f"exceptions, slowest {stats['slowest_s']:.3f} s\n"
            )


def _write(data: bytes, suffix: str) -> Path:
    fd, name = tempfile.mkstemp(suffix=suffix)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    return Path(name)


def test_a_hand_eye_of_huge_numbers_is_refused_without_a_numpy_warning(tmp_path):
    # (found by the fuzz above: R R^T of 1e300 overflowed before the check refused it)
    from stereograph.core.api import NodeError

    he = json.loads((LIVE / "hand_eye.json").read_text())
    he["T_base_from_left"][0][0] = 1e300
    f = tmp_path / "hand_eye.json"
    f.write_text(json.dumps(he))
    with pytest.raises(NodeError, match="not a rigid 4x4 transform"):
        _hand_eye(f)
