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
    out = tmp_path / "tuned.toml"
    out.write_text("old\n", encoding="utf-8")

    def refused(*_: object) -> Path:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("gaits.output._new_beside", refused)
    write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "new\n"


def test_a_rename_refused_in_a_sticky_folder_writes_in_place_and_leaves_nothing_beside(tmp_path, monkeypatch) -> None:
    """(Another user's file in /tmp, say: only its owner or the folder's may rename over it. Root may, so the
    refusal is given by hand.)"""
    out = tmp_path / "tuned.toml"
    out.write_text("old\n", encoding="utf-8")
    inode = out.stat().st_ino

    def refused(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "replace", refused)
    write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "new\n" and out.stat().st_ino == inode
    assert [p.name for p in tmp_path.iterdir()] == ["tuned.toml"]


def test_a_long_name_is_replaced_whole_too(tmp_path: Path) -> None:
    """The file beside it has a short name of its own: one made from a 238-byte name was too long (255 at most) and
    the write went in place, half written on a full disk."""
    out = tmp_path / ("t" * 245 + ".toml")
    out.write_text("old\n", encoding="utf-8")
    inode = out.stat().st_ino
    write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "new\n" and out.stat().st_ino != inode  # renamed over: a new file


def test_a_file_with_another_name_is_written_in_place_so_both_names_see_it(tmp_path: Path) -> None:
    out, other = tmp_path / "tuned.toml", tmp_path / "other.toml"
    out.write_text("old\n", encoding="utf-8")
    os.link(out, other)
    write_whole(out, "new\n")
    assert other.read_text(encoding="utf-8") == "new\n" and os.path.samefile(out, other)


@pytest.mark.skipif(os.geteuid() != 0, reason="only root can give a file to another user")
def test_another_users_file_keeps_its_owner(tmp_path: Path) -> None:
    out = tmp_path / "tuned.toml"
    out.write_text("old\n", encoding="utf-8")
    os.chown(out, 65534, 65534)
    write_whole(out, "new\n")
    assert out.read_text(encoding="utf-8") == "new\n"
    assert (out.stat().st_uid, out.stat().st_gid) == (65534, 65534)


def test_a_link_loop_is_an_os_error_the_command_answers_by_printing_the_gait(tmp_path: Path) -> None:
    """A RuntimeError from ``Path.resolve`` escaped the command's OSError handler: the gait was lost."""
    (tmp_path / "a.toml").symlink_to(tmp_path / "b.toml")
    (tmp_path / "b.toml").symlink_to(tmp_path / "a.toml")
    with pytest.raises(OSError):
        write_whole(tmp_path / "a.toml", "new\n")


def test_the_check_before_the_search_keeps_a_dangling_link_a_link(tmp_path: Path) -> None:
    """``refused`` made the link's target to see that it could be written, then removed the link instead of it."""
    from gaits.model import LIBRARY, load
    from gaits.output import refused

    link, target = tmp_path / "tuned.toml", tmp_path / "elsewhere" / "tuned.toml"
    target.parent.mkdir()
    link.symlink_to(target)
    assert refused(link, LIBRARY / "caterpillar.toml", load(LIBRARY / "caterpillar.toml")) is None
    assert link.is_symlink() and not target.exists()
    write_whole(link, "new\n")
    assert link.is_symlink() and target.read_text(encoding="utf-8") == "new\n"
