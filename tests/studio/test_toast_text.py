"""A toast shows its body as written: the markdown escapes the status line needs are not shown in it."""

from __future__ import annotations

from web.confirm import plain, unplain


def test_a_toast_shows_a_name_as_written_not_its_markdown_escapes() -> None:
    for hostile in ["run.mcap", "a\\b", "<img src=x>", "**x**", "m1_[2](3)!#&~|`{}", "ü\\.\\\\"]:
        assert unplain(plain(hostile)) == hostile
    assert unplain(plain("run.mcap") + " opened") == "run.mcap opened"
