"""radarcal.board: the one BoardSpec / object_points used by detection (intrinsics) and rendering (synth)."""

import numpy as np
import pytest

from radarcal.board import BoardSpec, object_points


def test_one_definition_under_every_old_path():
    import radarcal.intrinsics.detect as detect
    import radarcal.synth as synth
    import radarcal.synth.board as synth_board

    assert detect.BoardSpec is BoardSpec and synth.BoardSpec is BoardSpec and synth_board.BoardSpec is BoardSpec
    assert detect.object_points is object_points and synth.board_object_points is object_points


def test_object_points_follow_opencv_for_both_kinds():
    chess = BoardSpec("chessboard", 4, 3, 0.02)
    obj = object_points(chess)
    # row-major inner corners, origin at the first one: corner 5 = row 1, col 1
    assert obj.shape == (12, 3) and np.allclose(obj[0], 0) and np.allclose(obj[5], [0.02, 0.02, 0])
    for legacy in (False, True, None):
        cb = BoardSpec("charuco", 6, 5, 0.03, 0.02, "DICT_5X5_100", legacy=legacy)
        np.testing.assert_allclose(object_points(cb), cb.cv_board().getChessboardCorners(), atol=1e-12)
        assert cb.grid_shape == (4, 5) and cb.n_corners == 20


def test_invalid_specs_raise_one_line_value_errors():
    for args, word in [(("circles", 9, 6, 0.02), "board"), (("chessboard", 1, 6, 0.02), "2x2"),
                       (("chessboard", 9, 6, -1.0), "square"), (("charuco", 8, 8, 0.02), "marker"),
                       (("charuco", 8, 8, 0.02, 0.03), "marker"), (("charuco", 8, 8, 0.02, 0.015, "DICT_NOPE"), "dictionary")]:
        with pytest.raises(ValueError, match=word) as e:
            BoardSpec(*args)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="legacy"):
        BoardSpec("charuco", 8, 8, 0.02, 0.015, legacy="bad")  # type: ignore[arg-type]


def test_dict_round_trip_and_chessboard_defaults():
    cb = BoardSpec("charuco", 8, 6, 0.03, 0.022, "DICT_4X4_1000", legacy=True, margin=0.01)
    assert BoardSpec.from_dict(cb.to_dict()) == cb
    auto = BoardSpec("charuco", 8, 6, 0.03, 0.022)
    assert auto.legacy is None and BoardSpec.from_dict(auto.to_dict()) == auto
    chess = BoardSpec("chessboard", 9, 6, 0.025)
    d = chess.to_dict()
    # truth.json keys and the chessboard values of radarcal-synth-board/1
    assert d == {"type": "chessboard", "cols": 9, "rows": 6, "square": 0.025, "marker": None, "dictionary": None,
                 "legacy": False, "margin": 0.025, "squares_x": 10, "squares_y": 7, "n_corners": 54}
    assert BoardSpec.from_dict(d) == chess and chess.margin == chess.paper_margin == 0.025
    np.testing.assert_allclose(chess.squares_extent, (-0.025, -0.025, 0.225, 0.15))
    np.testing.assert_allclose(chess.centre, [0.1, 0.0625, 0.0])
