"""One team colour table for the report and the live minimap."""

from radarcal.runtime.minimap import _colour
from radarcal.teams import TEAM_SHADES, track_colours


def _bgr(hex_rgb: str) -> tuple[int, int, int]:
    r, g, b = (int(hex_rgb[i : i + 2], 16) for i in (1, 3, 5))
    return (b, g, r)


def test_minimap_draws_each_robot_in_the_report_shade_of_its_team():
    for label in ("red_1", "red_3", "blue_4", "blue_7"):
        team = label.split("_")[0]
        bgr = _colour(label)
        assert bgr == _bgr(track_colours([label])[label])
        assert _bgr(track_colours([label])[label]) in [_bgr(h) for h in TEAM_SHADES[team]]
        b, _, r = bgr
        assert (r > b) if team == "red" else (b > r), label


def test_minimap_trails_are_lighter_and_unlabelled_tracks_grey():
    assert all(c2 >= c1 for c1, c2 in zip(_colour("blue_4"), _colour("blue_4", 40)))
    assert sum(_colour("blue_4", 40)) > sum(_colour("blue_4"))
    b, g, r = _colour("#12")
    assert b == g == r
