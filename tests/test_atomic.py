import json

import pytest

from mop.atomic import atomic_path, write_json


def test_failed_write_keeps_previous_file(tmp_path):
    target = tmp_path / "report.json"
    write_json(target, {"version": 1})
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half of a new fi")
        raise RuntimeError("crash mid-write")
    assert json.loads(target.read_text()) == {"version": 1}
    assert list(tmp_path.iterdir()) == [target]  # no temporary left behind


def test_successful_write_replaces(tmp_path):
    target = tmp_path / "sub" / "a.json"
    write_json(target, [1])
    write_json(target, [2])
    assert json.loads(target.read_text()) == [2]
