"""``l3gs_opt.output_files.write_atomic``: the one way result files are written whole."""

from __future__ import annotations

import pytest

from l3gs_opt.output_files import write_atomic


def test_bytes_text_and_writer_functions(tmp_path):
    assert write_atomic(tmp_path / "a.bin", b"\x00\x01") == tmp_path / "a.bin"
    assert (tmp_path / "a.bin").read_bytes() == b"\x00\x01"
    write_atomic(tmp_path / "t.txt", "g\u00e9n\u00e9ral\n", fsync=True)
    assert (tmp_path / "t.txt").read_bytes() == "g\u00e9n\u00e9ral\n".encode("utf-8")
    write_atomic(tmp_path / "f.bin", lambda fh: fh.write(b"abc"))
    assert (tmp_path / "f.bin").read_bytes() == b"abc"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "f.bin", "t.txt"]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("old")

    def half(fh):
        fh.write(b"half of it")
        raise KeyboardInterrupt   # a Ctrl-C in the middle

    with pytest.raises(KeyboardInterrupt):
        write_atomic(target, half)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_a_folder_in_the_way_is_an_os_error_and_leaves_nothing(tmp_path):
    """The sweep's case: tables.json was a folder, and tables.json.part stayed behind."""
    (tmp_path / "tables.json").mkdir()
    with pytest.raises(OSError):
        write_atomic(tmp_path / "tables.json", "{}")
    assert [p.name for p in tmp_path.iterdir()] == ["tables.json"]
