"""The browser tests' two xdist groups (tests/studio/browser.py): a module named for the second group that no longer
exists, or that sets no browser marks, would leave the groups unbalanced without a word."""

from __future__ import annotations

import importlib
from pathlib import Path

from .browser import SECOND_CHROMIUM, browser_group

HERE = Path(__file__).parent


def _group(module: str) -> str | None:
    """The xdist group module ``module`` of this folder puts its tests in, if any."""
    marks = getattr(importlib.import_module(f"{__package__}.{module}"), "pytestmark", [])
    groups = [m.args[0] for m in (marks if isinstance(marks, list) else [marks]) if m.name == "xdist_group"]
    return groups[0] if groups else None


def _browser_modules() -> set[str]:
    """This folder's test modules whose tests are in a browser group."""
    return {path.stem for path in HERE.glob("test_*.py") if (_group(path.stem) or "").startswith("browser")}


def test_every_module_named_for_the_second_chromium_is_a_browser_test_module() -> None:
    modules = _browser_modules()
    assert not SECOND_CHROMIUM - modules, sorted(SECOND_CHROMIUM - modules)


def test_the_browser_modules_are_split_between_two_groups() -> None:
    modules = _browser_modules()
    assert len(modules) >= 16 and "test_browser_groups" not in modules, sorted(modules)
    assert all(_group(module) == browser_group(f"tests.studio.{module}") for module in modules)
    assert {browser_group(f"tests.studio.{module}", 4) for module in modules} == {"browser-a", "browser-b"}
    assert {browser_group(f"tests.studio.{module}", 2) for module in modules} == {"browser"}
    assert browser_group("tests.studio.test_drive_e2e", 4) == "browser-b"
    assert browser_group("tests.studio.test_studio_e2e", 4) == "browser-a"
