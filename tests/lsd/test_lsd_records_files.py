"""The records file a resumable LSD benchmark streams its trials to, read back when a user's copy is
damaged: a file that is not UTF-8 is refused naming it (never the codec's bare message)."""

import pytest

from jaxsem.lsd import read_records
from jaxsem.lsd._experiment import _RecordStream, records_stamp  # layers: white-box


def test_records_that_are_not_utf8_are_refused_naming_the_file(tmp_path):
    path = tmp_path / "r.records.jsonl"
    path.write_bytes(b'{"stamp": {"map": "caf\xe9"}}\n')
    for read in (read_records, records_stamp, lambda p: _RecordStream(p, ["uniform"], {"map": "x"})):
        with pytest.raises(ValueError, match=r"r\.records\.jsonl: not a readable records file \(not UTF-8"):
            read(path)
    assert path.read_bytes() == b'{"stamp": {"map": "caf\xe9"}}\n'  # left as it was


def test_records_read_back_with_their_stamp(tmp_path):
    path = tmp_path / "r.records.jsonl"
    _RecordStream(path, ["uniform"], {"map": "x"})
    path.write_text(path.read_text() + '{"building": 0, "set": "II", "trial": 0, "n": 60}\n')
    assert records_stamp(path) == {"map": "x"}
    assert read_records(path) == [{"building": 0, "set": "II", "trial": 0, "n": 60}]
