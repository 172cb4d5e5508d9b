"""The browser tests' two xdist groups (tests/studio/browser.py): a module named for the second group that no longer
exists, or that sets no browser marks, would leave the groups unbalanced without a word."""

from __future__ import annotations

from pathlib import Path

from .browser import SECOND_CHROMIUM, browser_group

HERE = Path(__file__).parent


def _browser_modules() -> set[str]:
    return {path.stem for path in HERE.glob("test_*.py") if "marks(__name__)" in path.read_text(encoding="utf-8")}


def test_every_module_named_for_the_second_chromium_is_a_browser_test_module() -> None:
    modules = _browser_modules()
    assert not SECOND_CHROMIUM - modules, sorted(SECOND_CHROMIUM - modules)


def test_the_browser_modules_are_split_between_two_groups() -> None:
    groups = {browser_group(f"tests.studio.{module}") for module in _browser_modules()}
    assert groups == {"browser-a", "browser-b"}
    assert browser_group("tests.studio.test_drive_e2e") == "browser-b"
    assert browser_group("tests.studio.test_studio_e2e") == "browser-a"
