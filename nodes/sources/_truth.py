"""Ground-truth files for the file sources, and the train / test split they decide.

A truth file lists measured ball centres by **pair id**. A pair id is the image file's stem
without its side token (``left`` / ``right`` / ``L`` / ``R``, any case) and the ``_ - .`` around
it: ``left01.png`` and ``right01.png`` -> ``01``; ``007_left.png`` -> ``007``;
``scene3-R.jpg`` -> ``scene3``; with ``left/`` and ``right/`` folders, ``left/a.png`` -> ``a``.
Other characters than letters, digits and ``_ . -`` become ``_``.

Formats:

* CSV with a header: ``id``, the centre in the left-camera frame ``x_cm, y_cm, z_cm`` and/or in
  the table frame ``table_x_cm, table_y_cm, table_z_cm``, optionally ``radius_cm`` and ``split``.
  Any other column is refused (it would be ignored), naming the closest known name.
* JSON: ``{id: {"center_left_cm": [x, y, z], "center_table_cm": [...], "split": "train"}}`` or a
  list of such records with an ``"id"`` key. An id (or a field of one record) given twice is
  refused: a JSON reader keeps the last one, silently; so is a key the reader does not know
  (``center_cm``).

The split (:func:`truth_split`): the pairs the file lists are the **training** placements (used to
fit compensation and hand-eye), the others are the targets (``test``) -- unless the file has a
``split`` column / key (``train`` / ``test``), which then rules; pairs the file does not list are
targets. No random split is made when a truth file is given.
"""

from __future__ import annotations

import csv
import difflib
import json
from pathlib import Path

from stereograph.api import NodeError, data_file

__all__ = ["read_truth_file", "truth_split"]

_SPLITS = ("train", "test")
# every CSV column the reader knows; any other is refused (it would be ignored: `radius` for
# radius_cm, a typo'd tabel_z_cm beside x_cm,y_cm,z_cm)
COLUMNS = (
    "id",
    "x_cm",
    "y_cm",
    "z_cm",
    "table_x_cm",
    "table_y_cm",
    "table_z_cm",
    "radius_cm",
    "split",
)
# every key of a JSON record the reader knows (the same rule: `center_cm`, `centre_left_cm` would be
# ignored)
FIELDS = ("id", "center_left_cm", "center_table_cm", "radius_cm", "split")
_HEADER_HINT = (
    "CSV header: id,x_cm,y_cm,z_cm[,radius_cm][,table_x_cm,table_y_cm,table_z_cm][,split], "
    "comma-separated with a decimal point"
)


def _unknown_columns(
    fields: list[str], path: Path, known: tuple[str, ...] = COLUMNS, where: str = ""
) -> None:
    """Refuse a header with a column named twice, or with columns (JSON: a record's keys, ``where``
    naming the record) the reader does not know, naming each with its closest known name."""
    twice = sorted({f for f in fields if f and fields.count(f) > 1})
    if twice:  # (the reader keeps the last column of a name, silently)
        raise NodeError(
            f"truth file {path} has the column(s) {', '.join(twice)} twice (header: "
            f"{', '.join(fields)}).",
            hint="keep one column of each name",
        )
    unknown = [f for f in fields if f and f not in known]
    if not unknown:
        return
    said = []
    for f in unknown:
        close = difflib.get_close_matches(f, known, n=1, cutoff=0.6) or difflib.get_close_matches(
            f"{f}_cm", known, n=1, cutoff=0.6
        )  # `radius` -> radius_cm
        said.append(f"{f!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    what = "column" if known is COLUMNS else "key"
    raise NodeError(
        f"truth file {path}{where} has {what}(s) it does not know: {', '.join(said)}; "
        "they would be "
        f"ignored. Known {what}s: {', '.join(known)}.",
        hint=f"rename the {what} to one of the known names (lengths in cm: convert millimetres "
        "first), or "
        "delete it",
    )


class _DuplicateKey(ValueError):
    pass


def _no_duplicate_keys(pairs: list[tuple[str, object]]) -> dict:
    """json.loads' object hook: a key given twice is refused (the parser keeps the last,
    silently)."""
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k)
        out[k] = v
    return out


def _xyz(row: dict, keys, where: str) -> list[float] | None:
    vals = [row.get(k) for k in keys]
    if all(v in (None, "") for v in vals):
        return None
    try:
        return [float(v) for v in vals]
    except (TypeError, ValueError):
        raise NodeError(
            f"{where}: {', '.join(keys)} must be numbers, got {vals}.",
            hint="write the ball centre in cm, e.g. 1.5,-2.0,42.3",
        ) from None


def _split_value(v, where: str) -> str | None:
    if v in (None, ""):
        return None
    s = str(v).strip().lower()
    if s not in _SPLITS:
        raise NodeError(
            f"{where}: split is {v!r}; it must be 'train' or 'test'.",
            hint="write train for placements to fit on, test for the targets",
        )
    return s


# (path, size, mtime, inode) -> what it gave: read once, not once per pair
_LAST_READ: dict[tuple, tuple] = {}


def read_truth_file(path: Path) -> tuple[dict[str, dict], dict[str, str] | None]:
    """Ground truth per pair id, and the file's explicit split when it has one (see
    :func:`_read_truth_file`).

    A source that reads its pairs one per call asks for the same file once per pair: the last file
    read is kept while its size, modification time and inode are unchanged (a million rows: once).
    """
    data_file(path, "a truth file (CSV or JSON)", "truth file", max_mb=512)
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns, st.st_ino)
    if key not in _LAST_READ:
        got = _read_truth_file(path)
        _LAST_READ.clear()
        _LAST_READ[key] = got
    return _LAST_READ[key]


def _read_truth_file(path: Path) -> tuple[dict[str, dict], dict[str, str] | None]:
    """Ground truth per pair id, and the file's explicit split when it has one.

    Returns
    -------
    truth : dict
        ``{pair_id: {"center_left_cm": [x,y,z] | None, "center_table_cm": [x,y,z] | None,
        "radius_cm": float | None, ...}}``
    split : dict or None
        ``{pair_id: "train" | "test"}`` for the rows that state one; None when the file has no
        ``split`` column / key at all.

    Raises
    ------
    NodeError
        A missing or malformed file; the message names the file and the line (CSV) or id (JSON).
    """
    if not path.is_file():
        raise NodeError(
            f"truth file {path} does not exist.", hint="fix the `truth` parameter or remove it"
        )
    if path.suffix.lower() == ".json":
        return _read_truth_json(path)
    return _read_truth_csv(path)


def _read_truth_json(path: Path) -> tuple[dict[str, dict], dict[str, str] | None]:
    """:func:`_read_truth_file` of a JSON file: ``{id: record}`` or a list of records with an id."""
    truth: dict[str, dict] = {}
    split: dict[str, str] = {}
    has_split = False
    try:
        data = json.loads(
            path.read_text(encoding="utf-8-sig"), object_pairs_hook=_no_duplicate_keys
        )
        if isinstance(data, list):
            ids = [str(r["id"]) for r in data]
            twice = next((i for k, i in enumerate(ids) if i in ids[:k]), None)
            if twice is not None:
                raise _DuplicateKey(twice)
            data = {str(r["id"]): r for r in data}
        items = {str(k): dict(v) for k, v in data.items()}
    except _DuplicateKey as exc:
        what = "field" if str(exc) in FIELDS else "id"
        raise NodeError(
            f"truth file {path}: {what} {str(exc)!r} is given twice; a JSON reader "
            "keeps only the "
            "last one, silently.",
            hint="keep one record per pair id (one value per field): the ball's measured "
            "centre for "
            "those images",
        ) from None
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise NodeError(
            f"cannot parse truth file {path}: {exc!r}.",
            hint="JSON {id: {center_left_cm: [x,y,z]}} or a list of records with an id",
        ) from None
    for pid, rec in items.items():
        _unknown_columns(list(rec), path, FIELDS, f", id {pid},")
        if "split" in rec:
            has_split = True
            s = _split_value(rec.pop("split"), f"truth file {path}, id {pid}")
            if s:
                split[pid] = s
        rec.setdefault("center_table_cm", None)
        truth[pid] = rec
    return truth, (split if has_split else None)


def _read_truth_csv(path: Path) -> tuple[dict[str, dict], dict[str, str] | None]:
    """:func:`_read_truth_file` of a CSV file (header ``id,x_cm,y_cm,z_cm,...``)."""
    truth: dict[str, dict] = {}
    split: dict[str, str] = {}
    try:
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark, which would become part of
        # `id`
        with path.open(newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in reader.fieldnames or []]
            _check_truth_header(path, fields)
            has_split = "split" in fields
            line_of: dict[str, int] = {}
            for row in reader:
                where = f"truth file {path}, line {reader.line_num}"
                pid, rec, s = _truth_row(row, fields, where, line_of, has_split)
                line_of[pid] = reader.line_num
                truth[pid] = rec
                if s:
                    split[pid] = s
    except (OSError, UnicodeDecodeError, csv.Error, ValueError) as exc:
        raise NodeError(
            f"cannot read truth file {path}: {exc}.",
            hint="CSV with a header id,x_cm,y_cm,z_cm (UTF-8), or JSON",
        ) from None
    return truth, (split if has_split else None)


def _check_truth_header(path: Path, fields: list[str]) -> None:
    """A truth CSV's header names an id and a centre, and no unknown column (NodeError)."""
    if "id" not in fields:
        sep = next((c for c in ";\t" if len(fields) == 1 and c in fields[0]), None)
        raise NodeError(
            f"truth file {path} has no `id` column (header: {', '.join(fields) or 'none'})"
            + (f": its columns are separated by {sep!r}, not commas." if sep else "."),
            hint=_HEADER_HINT,
        )
    centre_cols = {"x_cm", "y_cm", "z_cm"} <= set(fields) or {
        "table_x_cm",
        "table_y_cm",
        "table_z_cm",
    } <= set(fields)
    if not centre_cols:  # a header problem, said as one (it was blamed on line 2)
        raise NodeError(
            f"truth file {path} has no centre columns (header: "
            f"{', '.join(fields)}): the centre "
            "is x_cm,y_cm,z_cm (left-camera frame) or "
            "table_x_cm,table_y_cm,table_z_cm (cm).",
            hint="CSV header: "
            "id,x_cm,y_cm,z_cm[,radius_cm][,table_x_cm,table_y_cm,table_z_cm]"
            "[,split]; convert millimetres to cm",
        )
    _unknown_columns(fields, path)


def _truth_row(
    row: dict, fields: list[str], where: str, line_of: dict[str, int], has_split: bool
) -> tuple[str, dict, str | None]:
    """``(pair id, truth record, split or None)`` of one CSV row, checked (NodeError naming the
    line); ``line_of``: the line of each id read so far."""
    # values under no column name (an unnamed header cell, more cells than the header)
    # would be dropped
    extra = [
        x
        for k, v in row.items()
        if not (k or "").strip()
        for x in (v if isinstance(v, list) else [v])
        if x and x.strip()
    ]
    row = {(k or "").strip(): (v.strip() if isinstance(v, str) else v) for k, v in row.items()}
    if extra:
        raise NodeError(
            f"{where}: value(s) {', '.join(map(repr, extra))} stand under no "
            "column name "
            f"(header: {', '.join(fields)}).",
            hint=_HEADER_HINT,
        )
    pid = row.get("id")
    if not pid:
        raise NodeError(
            f"{where}: the id is empty.",
            hint="give every row the pair id of its images",
        )
    if pid in line_of:  # (the later row silently replaced the earlier one)
        raise NodeError(
            f"{where}: pair {pid} is listed again (first on line {line_of[pid]}).",
            hint="keep one row per pair: the ball's measured centre for those images",
        )
    left = _xyz(row, ("x_cm", "y_cm", "z_cm"), where)
    table = _xyz(row, ("table_x_cm", "table_y_cm", "table_z_cm"), where)
    if left is None and table is None:
        raise NodeError(
            f"{where}: pair {pid} has no centre (x_cm,y_cm,z_cm or table_x_cm,...).",
            hint="give the ball centre in the left-camera or the table frame, in cm",
        )
    radius = row.get("radius_cm")
    try:
        radius = float(radius) if radius else None
    except ValueError:
        raise NodeError(
            f"{where}: radius_cm must be a number, got {radius!r}.",
            hint="the ball's radius in cm, e.g. 2.0, or leave it empty",
        ) from None
    rec = {"center_left_cm": left, "center_table_cm": table, "radius_cm": radius}
    return pid, rec, _split_value(row.get("split"), where) if has_split else None


def truth_split(
    ids: list[str], truth: dict[str, dict], split: dict[str, str] | None, path: Path
) -> tuple[dict[str, str], list[str]]:
    """The split of each pair id decided by a truth file, and the warnings to show.

    Parameters
    ----------
    ids : list of str
        The pairs the images give.
    truth, split
        From :func:`read_truth_file`.
    path : Path
        The truth file, for the warnings.

    Returns
    -------
    splits : dict
        ``{pair_id: "train" | "test"}`` for every id.
    warnings : list of str
        Truth ids without images; images without truth.
    """
    if truth and ids and not set(truth) & set(ids):
        # (every figure of the accuracy report would be blank, and the compensation would have
        # nothing to fit)
        theirs = ", ".join(sorted(truth)[:5]) + (" ..." if len(truth) > 5 else "")
        ours = ", ".join(sorted(ids)[:5]) + (" ..." if len(ids) > 5 else "")
        zeros = {i.lstrip("0") or "0" for i in ids} & {str(t).lstrip("0") or "0" for t in truth}
        raise NodeError(
            f"none of the {len(ids)} pairs has a row in {path.name}: its ids ({theirs}) "
            "are not the "
            f"pairs' ({ours})"
            + (
                "; they match once leading zeros are ignored: a spreadsheet dropped "
                "them (format the id column as text)."
                if zeros
                else "."
            ),
            hint="the truth file's id column must hold the pair names the image files give "
            "(left_s000.png "
            "-> s000)",
        )
    if split is None:
        splits = {pid: "train" if pid in truth else "test" for pid in ids}
    else:
        splits = {pid: split.get(pid, "train" if pid in truth else "test") for pid in ids}
    warnings = []
    no_images = sorted(set(truth) - set(ids))
    if no_images:
        warnings.append(
            f"{len(no_images)} id(s) in {path.name} have no images: {', '.join(no_images[:20])}"
            + (" ..." if len(no_images) > 20 else "")
        )
    no_truth = [pid for pid in ids if pid not in truth]
    if no_truth:
        warnings.append(
            f"{len(no_truth)} pair(s) have no row in {path.name} (targets, no ground truth): "
            + ", ".join(no_truth[:20])
            + (" ..." if len(no_truth) > 20 else "")
        )
    return splits, warnings
