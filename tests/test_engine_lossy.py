"""Issue 13: pictures for people (``Out(lossy=True)``) are kept and saved as JPEG, once on disk, and
every reader gets the same decoded pixels whether the picture was computed now or read from the
cache."""

from __future__ import annotations

import textwrap
import uuid
from pathlib import Path

import numpy as np

from stereograph.core.runner import run_pipeline

PLUGIN = """\
import numpy as np
from stereograph.core.api import In, Out, node

@node("lossyUID.draw",
      outputs={"picture": Out("Image", save=True, lossy=True), "mask": Out("Image")})
def draw(params):
    rng = np.random.default_rng(1)
    img = np.zeros((120, 160, 3), np.uint8)
    img[30:90, 40:120] = (20, 120, 245)
    # noise: PNG's worst case
    img = np.clip(img + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8)
    return {"picture": img, "mask": (img[..., 0] > 100).astype(np.uint8) * 255}

@node("lossyUID.digest", inputs={"image": In("Image")},
      outputs={"digest": Out("Number", save=True)})
def digest(params, image):
    return {"digest": float(np.dot(image.ravel()[:5000].astype(np.float64), np.arange(5000) % 7))}
"""


def _pipeline(tmp_path: Path) -> Path:
    uid = uuid.uuid4().hex[:8]  # (a type name of its own: the registry is per process)
    plug = tmp_path / f"lossy_{uid}.py"
    plug.write_text(PLUGIN.replace("UID", uid))
    p = tmp_path / "p.yaml"
    p.write_text(
        textwrap.dedent(f"""\
        name: lossy
        plugins: [{plug}]
        nodes:
          draw: {{type: lossy{uid}.draw}}
          digest: {{type: lossy{uid}.digest, inputs: {{image: draw.picture}}}}
          mask_digest: {{type: lossy{uid}.digest, inputs: {{image: draw.mask}}}}
        """)
    )
    return p


def test_a_lossy_picture_is_one_jpeg_and_reads_the_same_fresh_or_cached(tmp_path):
    p = _pipeline(tmp_path)
    kw = dict(cache_dir=tmp_path / "c")
    fresh = run_pipeline(p, out_dir=tmp_path / "o1", **kw)
    assert fresh.ok
    jpg = tmp_path / "o1" / "draw" / "picture.jpg"
    assert jpg.is_file() and not (tmp_path / "o1" / "draw" / "picture.png").exists()
    entry_files = list((tmp_path / "c" / "objects").rglob("*.jpg"))
    # the run folder's file is the cache's
    assert len(entry_files) == 1 and entry_files[0].samefile(jpg)
    # the digest node read the decoded JPEG: recomputing it from the cached picture gives the same
    # number
    again = run_pipeline(p, out_dir=tmp_path / "o2", from_node="digest", **kw)
    assert again.status["draw"] == "cached" and again.status["digest"] == "ran"
    assert again.outputs("digest", "digest") == fresh.outputs("digest", "digest")
    assert np.array_equal(again.outputs("draw", "picture"), fresh.outputs("draw", "picture"))
    # a lossless output beside it stays PNG (exact); without the cache the picture is a JPEG too
    assert list((tmp_path / "c" / "objects").rglob("*.png"))
    nocache = run_pipeline(p, out_dir=tmp_path / "o3", use_cache=False)
    assert (tmp_path / "o3" / "draw" / "picture.jpg").is_file()
    assert nocache.outputs("digest", "digest") == fresh.outputs("digest", "digest")
    assert jpg.stat().st_size < 0.5 * (fresh.outputs("draw", "picture").nbytes)
    # ... whose file is the very JPEG its readers decoded (not a second generation of it)
    assert (tmp_path / "o3" / "draw" / "picture.jpg").read_bytes() == jpg.read_bytes()
