"""Issue 28 from the page: the studio's own robot runs module 2 from the board image in the emulator
(``--emulated-modules 2``); on the Modules tab a user uploads a new update image and clicks nothing else — every
module is offered it, the emulated board takes it, resets into it and says its new version, the Python modules are
skipped — and a file that is not an image is refused before anything is sent."""

from __future__ import annotations

import re
import shutil
import time

import pytest

from ..helpers import ARTIFACTS
from .browser import marks, open_page

pytestmark = [
    # in the suite again since the emulator's update work (docs/benchmarks.md, 2026-11-27): it was slow-marked when
    # an emulated board, run in real time under the suite's load, answered a firmware.image SET after over 30 s
    pytest.mark.timeout(420),  # before marks()'s 240 s: the closest timeout mark is the first
    *marks(__name__),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="make test installs gcc-arm-none-eabi"),
]
NEW = 0x000200


def _upload(page, path) -> None:
    with page.expect_file_chooser() as chooser:
        page.get_by_role("button", name="Update firmware (.img)").click()
    chooser.value.set_files(str(path))


def test_the_modules_tab_updates_the_emulated_boards_firmware_from_an_uploaded_image(start_studio, tmp_path, chromium):
    from playwright.sync_api import expect

    from asm_module.emulated import versioned_image
    from asm_module.firmware_image import image_bytes

    image = tmp_path / "module.img"
    image.write_bytes(image_bytes(versioned_image(NEW)))  # built in firmware/build, where the robot's emulator finds it
    bogus = tmp_path / "bogus.img"
    bogus.write_bytes(b"not an image" * 20)
    url, _, log = start_studio("--emulated-modules", "2", "--board-flash", "none")  # flashed as m2
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Modules").click()
    board = page.locator("td", has_text=re.compile(r"^C 0\.1\.0"))
    deadline = time.monotonic() + 180  # the robot child and its emulated board come up after the page
    while True:
        page.get_by_role("button", name="Read modules").click()
        try:
            expect(page.get_by_text(re.compile(r"Read 8 modules: 8 said their firmware"))).to_be_visible(timeout=15_000)
            expect(board).to_have_count(1, timeout=5_000)
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    _upload(page, bogus)
    expect(page.get_by_text(re.compile(r"⚠ .*(header|image)"))).to_be_visible(timeout=30_000)
    _upload(page, image)
    expect(page.get_by_text("m2: updated (0.1.0 -> 0.2.0)")).to_be_visible(timeout=300_000)
    expect(page.get_by_text(re.compile(r"m1: skipped"))).to_be_visible(timeout=5_000)
    expect(page.locator("td", has_text=re.compile(r"^C 0\.2\.0"))).to_have_count(1, timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "modules-update.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
