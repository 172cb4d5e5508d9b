"""``gaits.output.write_whole``, where ``gaits tune`` writes its result: whole or not at all, through a link to its
target, the replaced file's permissions kept, and in place where nothing can be made beside it."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from gaits.output import write_whole


def test_a_new_file_gets_the_umasks_permissions_and_nothing_is_left_beside_it(tmp_path: Path) -> None:
    umask = os.umask(0o027)
    try:
        write_whole(tmp_path / "new.toml", "a = 1\n")
    finally:
        os.umask(umask)
    assert (tmp_path / "new.toml").read_text(encoding="utf-8") == "a = 1\n"
    assert stat.S_IMODE((tmp_path / "new.toml").stat().st_mode) == 0o640  # as open() would make it, not mkstemp's 0600
    assert [p.name for p in tmp_path.iterdir()] == ["new.toml"]


def test_a_replaced_file_keeps_its_permissions_and_a_link_keeps_pointing_at_it(tmp_path: Path) -> None:
    target = tmp_path / "kept" / "tuned.toml"
    target.parent.mkdir()
    target.write_text("old\n", encoding="utf-8")
    target.chmod(0o604)
    link = tmp_path / "link.toml"
    link.symlink_to(target)
    write_whole(link, "new\n")
    assert link.is_symlink() and target.read_text(encoding="utf-8") == "new\n"
    assert stat.S_IMODE(target.stat().st_mode) == 0o604
    assert sorted(p.name for p in target.parent.iterdir()) == ["tuned.toml"]


def test_a_failed_write_leaves_the_old_file_and_no_partial_one(tmp_path: Path, monkeypatch) -> None:
    out = tmp_path / "tuned.toml"
    out.write_text("old\n", encoding="utf-8")

    def fails(*_: object) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", fails)
    with pytest.raises(OSError, match="No space left"):
        write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["tuned.toml"]


def test_in_a_folder_that_takes_no_new_file_a_writable_file_is_written_in_place(tmp_path: Path, monkeypatch) -> None:
    """(A folder without write permission; the suite runs as root, who may write there all the same, so the refusal
    to make a file in it is given by hand.)"""
    import tempfile

    out = tmp_path / "tuned.toml"
    out.write_text("old\n", encoding="utf-8")

    def refused(*_: object, **__: object) -> None:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refused)
    write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "new\n"
