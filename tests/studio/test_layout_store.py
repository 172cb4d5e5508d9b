"""The page's last layout kept across studio restarts (web/layout_store.py): written when it changes, read back,
and a missing, broken, huge or hostile file taken as no layout."""

from __future__ import annotations

import json

from web.layout_store import MAX_BYTES, LayoutStore

LAYOUT = {"version": 1, "window": 60.0, "plots": {"Live plot 1": [], "Live plot 2": ["m3/joint.angle"]}}


def test_a_layout_is_written_when_it_changes_and_read_back(tmp_path):
    path = tmp_path / "state" / "studio-layout.json"  # its directory made when first written
    store = LayoutStore(path)
    assert store.load() is None
    assert store.save(LAYOUT) and json.loads(path.read_text()) == LAYOUT
    before = path.stat().st_mtime_ns
    assert not store.save(dict(LAYOUT))  # the same layout: not written again
    assert path.stat().st_mtime_ns == before
    assert LayoutStore(path).load() == LAYOUT  # as a restarted studio reads it
    assert not list(path.parent.glob("*.tmp"))  # written whole, then renamed
    assert not LayoutStore(None).save(LAYOUT) and LayoutStore(None).load() is None


def test_a_broken_or_hostile_file_is_no_layout(tmp_path, caplog):
    path = tmp_path / "studio-layout.json"
    for content in (b"{not json", b"[1, 2]", b"\xff\xfe\x00", b"null", b" " * (MAX_BYTES + 1), b""):
        path.write_bytes(content)
        assert LayoutStore(path).load() is None, content[:20]
    path.unlink()
    path.mkdir()  # a directory where the file should be: neither read nor written, nothing raised
    assert LayoutStore(path).load() is None
    assert not LayoutStore(path).save(LAYOUT)
    assert "not restored" in caplog.text and "could not be kept" in caplog.text
