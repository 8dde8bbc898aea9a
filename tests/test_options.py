"""The option values shared by the command line and batch job files."""

import pytest

from marionette.camera import MAX_IMAGE_SIDE
from marionette.options import MAX_PARTS, parse_background, parse_focal, parse_part_seeds, parse_parts, parse_size


@pytest.mark.parametrize("value, expected", [
    ("1,1,1", (1.0, 1.0, 1.0)), ([0, 0.5, 1], (0.0, 0.5, 1.0)), ("255,0,51", (1.0, 0.0, 0.2)),
    ([255, 255, 0], (1.0, 1.0, 0.0)),
])
def test_background_takes_text_and_lists_in_either_range(value, expected):
    assert parse_background(value) == pytest.approx(expected)


@pytest.mark.parametrize("value", ["1,1", "a,b,c", [300, 0, 0], [-1, 0, 0], [True, 0, 0], "nan,0,0", 5, None])
def test_bad_backgrounds_are_refused(value):
    with pytest.raises(ValueError, match="must be"):
        parse_background(value)


@pytest.mark.parametrize("value, expected", [("640x480", (640, 480)), ("16X16", (16, 16)), ([512, 256], (512, 256))])
def test_size(value, expected):
    assert parse_size(value) == expected


@pytest.mark.parametrize("value", ["8x8", "640", "640x480x3", [640.5, 480], f"{MAX_IMAGE_SIDE + 1}x16", "axb"])
def test_bad_sizes_are_refused(value):
    with pytest.raises(ValueError, match="must be"):
        parse_size(value)


@pytest.mark.parametrize("value, expected", [("auto", "auto"), ("3", 3), (1, 1), (MAX_PARTS, MAX_PARTS)])
def test_parts(value, expected):
    assert parse_parts(value) == expected


@pytest.mark.parametrize("value", ["0", 0, MAX_PARTS + 1, "two", True, 2.0, "-1", ""])
def test_bad_part_counts_are_refused(value):
    with pytest.raises(ValueError, match="must be 'auto' or an integer"):
        parse_parts(value)


@pytest.mark.parametrize("value, expected", [("auto", "auto"), ("850", 850.0), (612.5, 612.5), ("1e3", 1000.0)])
def test_focal_lengths(value, expected):
    assert parse_focal(value) == expected


@pytest.mark.parametrize("value", ["wide", "0", -3, "nan", "inf", True, None, ""])
def test_bad_focal_lengths_are_refused(value):
    with pytest.raises(ValueError, match="must be 'auto' or a positive number"):
        parse_focal(value)


def test_part_seeds_from_the_command_line_and_from_a_job_file_agree():
    assert parse_part_seeds(["0:10,20", "1:30.5,4"]) == {0: (10.0, 20.0), 1: (30.5, 4.0)}
    assert parse_part_seeds({"0": [10, 20], "1": "30.5,4"}) == {0: (10.0, 20.0), 1: (30.5, 4.0)}


@pytest.mark.parametrize("value", [["0:10"], ["x:1,2"], ["1,2"], [], {}, {"a": [1, 2]}, {"0": [1]}, "0:1,2"])
def test_bad_part_seeds_are_refused(value):
    with pytest.raises(ValueError, match="must be"):
        parse_part_seeds(value)
