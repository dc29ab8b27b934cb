"""Reading a corpus entry: hostile YAML is refused with a short message, as in a spec."""

from __future__ import annotations

import pytest

from hritest.corpus import CorpusError, load_entry

BOMB = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"a{i}: &a{i} [*a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}, *a{i - 1}]\n"
    for i in range(1, 9)
)


def test_an_alias_bomb_in_an_entry_is_refused_with_a_short_message(tmp_path):
    path = tmp_path / "teleop" / "0123456789ab.yaml"
    path.parent.mkdir()
    path.write_text("format: 2\n" + BOMB)
    with pytest.raises(CorpusError, match="YAML aliases") as caught:
        load_entry(path)
    assert len(str(caught.value)) < 400


def test_a_duplicate_key_in_an_entry_is_refused(tmp_path):
    path = tmp_path / "teleop" / "0123456789ab.yaml"
    path.parent.mkdir()
    path.write_text("format: 2\nstatus: open\nstatus: fixed\n")
    with pytest.raises(CorpusError, match="duplicate key 'status'"):
        load_entry(path)
