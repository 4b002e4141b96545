"""Text files a user hands the package are read within a byte budget: a file over it is refused
by name, with its size and the budget, before its bytes are read."""

import pytest

from jaxsem._files import MAX_TEXT_BYTES, read_json, read_text  # layers: white-box


def test_text_over_its_budget_is_refused_naming_file_size_and_budget(tmp_path):
    path = tmp_path / "groundtruth.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n" * 100, encoding="utf-8")
    size = path.stat().st_size
    with pytest.raises(ValueError, match=rf"groundtruth.txt: {size:,} bytes, more than the max_bytes=1,000 a TUM list"):
        read_text(path, "TUM list", max_bytes=1000)
    assert read_text(path, max_bytes=size) == path.read_text()  # at the budget: read
    assert MAX_TEXT_BYTES >= 2**20  # the default holds any real sequence list


def test_json_goes_through_the_same_budget(tmp_path):
    path = tmp_path / "scene_gt.json"
    path.write_text('{"a": [1, 2, 3]}', encoding="utf-8")
    assert read_json(path) == {"a": [1, 2, 3]}
    with pytest.raises(ValueError, match=r"scene_gt.json: 16 bytes, more than the max_bytes=8"):
        read_json(path, max_bytes=8)


@pytest.mark.parametrize("budget", [0, -5, 1.5, True, "100"])
def test_a_budget_that_is_no_positive_whole_number_is_refused(tmp_path, budget):
    path = tmp_path / "a.txt"
    path.write_text("x", encoding="utf-8")
    with pytest.raises(ValueError, match="max_bytes: expected a positive whole number"):
        read_text(path, max_bytes=budget)


def test_unreadable_and_non_utf8_text_name_the_file(tmp_path):
    with pytest.raises(ValueError, match=r"missing.txt: cannot read the detections file"):
        read_text(tmp_path / "missing.txt", "detections file")
    bad = tmp_path / "latin.txt"
    bad.write_bytes(b"caf\xe9\n")
    with pytest.raises(ValueError, match=r"latin.txt: not a readable text file \(not UTF-8 text: byte 3\)"):
        read_text(bad)
