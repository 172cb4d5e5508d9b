"""The page's last layout kept across studio restarts (web/layout_store.py): written when it changes, read back,
and a missing, broken, huge or hostile file taken as no layout."""

from __future__ import annotations

import json
import re

import pytest

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


NOT_LAYOUTS = [  # (content, what the refusal says of it)
    (b"{not json", "not JSON"),
    (b"[1, 2]", "not a JSON object"),
    (b"\xff\xfe\x00", "not UTF-8"),
    (json.dumps({**LAYOUT, "version": 99}).encode(), "version 99"),
]
NOT_THE_PAGES = [  # layouts in form, but not of this page's plots: the page's own check refuses them
    (json.dumps({"window": 60.0, "plots": {"Live plot 9": []}}).encode(), "Live plot 1"),
    (json.dumps({"window": 7.0, "plots": {}}).encode(), "a window of one of"),
    (json.dumps({"window": 60.0, "plots": {"Live plot 1": "m1/joint.angle"}}).encode(), "node/attribute"),
]


def test_a_file_that_is_not_a_layout_is_refused_by_name_and_never_written_over(tmp_path, caplog):
    """Issue 29's review: a --layout file that was not a layout (a mistyped path onto the user's own JSON, a layout
    of a later version) was replaced by an empty layout at the page's first save, and version 99 was taken as a
    layout. Now it is refused, its name and the reason said, and it stays as it was."""
    path = tmp_path / "mine.json"
    for content, why in NOT_LAYOUTS:
        path.write_bytes(content)
        store = LayoutStore(path)
        assert store.load() is None, content
        assert not store.save(LAYOUT) and path.read_bytes() == content  # the user's file, as it was
        assert store.refused is not None and f"{path} is not a layout" in store.refused and why in store.refused
        assert f"{path} is not a layout" in caplog.text and why in caplog.text
        caplog.clear()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.json"]  # nothing written beside it either


def test_a_layout_of_other_plots_is_refused_by_the_pages_check(tmp_path):
    from web.monitor_panel import check_layout

    path = tmp_path / "mine.json"
    for content, why in NOT_THE_PAGES:
        path.write_bytes(content)
        store = LayoutStore(path, check=check_layout)
        assert store.load() is None and store.refused is not None and why in store.refused, content
        assert not store.save(LAYOUT) and path.read_bytes() == content
    path.write_bytes(json.dumps(LAYOUT).encode())
    assert LayoutStore(path, check=check_layout).load() == LAYOUT


def test_a_directory_as_the_layout_file_leaves_nothing_beside_it(tmp_path, caplog):
    """``--layout DIR`` (the command line refuses it now) wrote ``DIR.tmp`` beside it at each change."""
    folder = tmp_path / "layouts"
    folder.mkdir()
    store = LayoutStore(folder)
    assert not store.save(LAYOUT)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["layouts"] and not any(folder.iterdir())
    assert store.refused is not None and str(folder) in store.refused and "directory" in store.refused
    assert f"could not be kept in {folder}" in caplog.text


def test_a_layout_of_another_version_is_refused_naming_the_file_and_the_version(tmp_path):
    path = tmp_path / "later.json"
    path.write_text(json.dumps({**LAYOUT, "version": 99}))
    store = LayoutStore(path)
    assert store.load() is None  # it was read as a layout of this studio's
    assert store.refused is not None and f"{path} is not a layout: version 99" in store.refused

    from web.layout_store import read_layout

    assert read_layout(json.dumps(LAYOUT).encode(), "ok.json") == LAYOUT
    for version in (99, 0, "1", True, None):
        with pytest.raises(ValueError, match=r"^a\.json is not a layout: version .*, and this studio reads .* 1 only"):
            read_layout(json.dumps({**LAYOUT, "version": version}).encode(), "a.json")


def test_the_page_says_the_layout_file_is_not_one_and_refuses_an_upload_of_another_version(tmp_path, caplog):
    """The studio started with a --layout file that is not a layout: the page's saves leave it alone, and its log
    and the Monitor tab (by the layout buttons) say which file and why; Load layout names the file it refuses."""
    from types import SimpleNamespace

    from server.studio import Studio, StudioOptions

    path = tmp_path / "notes.json"
    content = b'{"my notes": "half-written'  # the user's own file, mistyped for --layout
    path.write_bytes(content)
    studio = Studio(StudioOptions(port=0, layout=path, recordings=tmp_path / "recordings"))
    try:
        monitor = studio.app.monitor
        monitor.plots[0].window = 30.0  # a change of the layout
        monitor._keep_layout()  # what the page's refresh does with it, 20 times a second
        assert path.read_bytes() == content and not list(tmp_path.glob("*.tmp"))  # never written over
        line = re.sub(r"\\(.)", r"\1", monitor.layout_line.content)  # as the page shows it (web.confirm.plain)
        assert "notes.json is not a layout: not JSON" in line, line
        assert f"{path} is not a layout: not JSON" in caplog.text
        later = {**LAYOUT, "version": 2}
        with pytest.raises(ValueError, match="version 2"):
            monitor.apply_layout(later)
        upload = SimpleNamespace(name="later.json", content=json.dumps(later).encode())
        with pytest.raises(ValueError, match=r"later\\?\.json is not a layout: version 2"):
            monitor._on_load(SimpleNamespace(target=SimpleNamespace(value=upload)))
        assert monitor.plots[0].window == 30.0  # nothing changed
    finally:
        studio.close()


def test_a_layout_not_restored_is_kept_in_its_file_until_the_plots_change(tmp_path):
    """Issue 29's third review: a saved layout naming a module not up at the studio's start was written over with
    the empty plots the page showed once its restore gave up; the page spares the file until the user changes
    something."""
    path = tmp_path / "studio-layout.json"
    LayoutStore(path).save(LAYOUT)
    store = LayoutStore(path)
    assert store.load() == LAYOUT
    empty = {"version": 1, "window": 10.0, "plots": {"Live plot 1": [], "Live plot 2": []}}
    store.spare(empty)  # the restore gave up: what the page shows now
    assert not store.save(empty) and json.loads(path.read_text()) == LAYOUT
    changed = {**empty, "plots": {"Live plot 1": ["m1/joint.angle"], "Live plot 2": []}}
    assert store.save(changed) and json.loads(path.read_text()) == changed
