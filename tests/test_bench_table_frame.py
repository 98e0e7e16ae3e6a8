"""The table frame from a chessboard lying on the table (calibrator.table_frame)."""

import cv2
import numpy as np
import pytest

from nodes.calibrators.table_frame import TableFrameParams, table_frame
from nodes.calibrators.truth import truth_calibration
from nodes.sources._boards import render_table_board
from nodes.sources._rig import make_rig
from nodes.sources.synthetic import SyntheticParams, _rig_kwargs
from stereograph.core.api import NodeError


@pytest.fixture(scope="module")
def rig():
    return make_rig(**_rig_kwargs(SyntheticParams(n_scenes=0, n_views=0, seed=0)))


def _views(left, right):
    return {
        "views": [{"id": "table", "left": left, "right": right}],
        "image_size": [640, 480],
        "board": {"type": "chessboard", "cols": 9, "rows": 6, "square_cm": 2.5},
    }


def _frame(rig, left, right, **kw):
    return table_frame(
        TableFrameParams(**kw), _views(left, right), truth_calibration(rig["truth"])
    )["table_frame"]


@pytest.mark.slow
@pytest.mark.parametrize("yaw", [0, 180, 90])
def test_frame_matches_the_board_on_the_rig(rig, yaw):
    # A board turned by 90 or 180 degrees gives the frame of its own corner nearest the cameras on
    # the left.
    left, right, T_true = render_table_board(rig, yaw_deg=yaw)
    tf = _frame(rig, left, right)
    T = tf["T_table_from_left"]
    assert np.abs(T[:3, 3] - T_true[:3, 3]).max() < 0.05
    assert np.degrees(np.linalg.norm(cv2.Rodrigues(T[:3, :3] @ T_true[:3, :3].T)[0])) < 0.05
    assert tf["disagreement"]["translation_cm"] < 0.1 and tf["disagreement"]["rotation_deg"] < 0.1
    assert tf["rig"]["image_size"] == [640, 480]


@pytest.mark.slow
def test_board_not_found_and_ambiguous_board_are_clear_errors(rig):
    left, right, _ = render_table_board(rig, yaw_deg=45)
    with pytest.raises(NodeError, match="ambiguous"):
        _frame(rig, left, right)
    blank = np.full((480, 640, 3), 128, np.uint8)
    with pytest.raises(NodeError, match="no 9x6 chessboard found in the left image") as e:
        _frame(rig, blank, right)
    assert "view table" in e.value.message and e.value.hint


def test_a_calibration_that_does_not_fit_is_refused(rig):
    left, right, _ = render_table_board(rig)
    cal = truth_calibration(rig["truth"])
    # baseline 10 % off: the two views put the board in different places
    cal["T_cm"] = cal["T_cm"] * 1.1
    with pytest.raises(NodeError, match="differ by"):
        table_frame(TableFrameParams(), _views(left, right), cal)


def test_a_calibration_in_squares_with_a_board_in_cm_is_a_clear_error(rig):
    # (it failed as "the calibration does not fit these images", 27 % disagreement, with no word of
    # units)
    left, right, _ = render_table_board(rig, yaw_deg=0)
    cal = dict(truth_calibration(rig["truth"]), length_unit="squares")
    with pytest.raises(
        NodeError, match="calibration's lengths are in squares but the board's square size is in cm"
    ) as e:
        table_frame(TableFrameParams(), _views(left, right), cal)
    assert "cm_per_unit" in e.value.hint
    views = _views(left, right)
    # the reverse: the table pair's source without square_cm
    views["board"]["length_unit"] = "squares"
    with pytest.raises(NodeError, match="in cm but the board's square size is in squares"):
        table_frame(TableFrameParams(), views, truth_calibration(rig["truth"]))


def test_a_swapped_table_pair_is_named_as_swapped_not_blamed_on_the_calibration(rig):
    # (it was refused as "the calibration does not fit these images: calibrate again")
    left, right, _ = render_table_board(rig)
    views = _views(right, left)
    views["views"][0].update(left_path="table/left_table.png", right_path="table/right_table.png")
    with pytest.raises(
        NodeError,
        match=r"exchanged, the two images agree .* view table are swapped "
        r"\(table/left_table.png, table/right_table.png\)",
    ) as e:
        table_frame(TableFrameParams(), views, truth_calibration(rig["truth"]))
    assert "swap the table pair's left and right" in e.value.hint


def test_a_table_board_of_another_square_size_than_the_calibration_is_named(rig):
    # bench-table.yaml says 2.5 cm squares; a bench calibrated with its own board's square_cm was
    # told only "the calibration does not fit these images"
    left, right, _ = render_table_board(rig)  # 2.5 cm squares
    cal = dict(truth_calibration(rig["truth"]), board={"cols": 9, "rows": 6, "square_cm": 2.5})
    views = _views(left, right)
    views["board"]["square_cm"] = 3.0
    with pytest.raises(
        NodeError, match=r"made with a board of 2.5 cm squares, and this board's square_cm is 3"
    ) as e:
        table_frame(TableFrameParams(), views, cal)
    assert "board.square_cm=2.5" in e.value.hint
