"""``asm-flash`` (server/flash.py) against emulated boards on one bus: the selected modules are updated together and
each one's old and new version printed; what is not an image, or a selection with nobody on the bus, is an error
before anything is written."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from asm_module.flash import Settings
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import fresh_name

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="the board image needs arm-none-eabi-gcc"),
]


def test_asm_flash_updates_the_selected_modules_and_prints_their_versions(tmp_path: Path, capsys) -> None:
    from asm_module.emulated import EmulatedModule, versioned_image
    from asm_module.firmware_image import check
    from asm_module.firmware_image import main as make_image
    from server.flash import main

    elf_path = tmp_path / "new.elf"
    image = tmp_path / "new.img"
    from asm_module.firmware_build import build_board_image

    versioned_image(0x000203)
    shutil.copy(build_board_image(0x000203), elf_path)
    assert make_image([str(elf_path), str(image)]) == 0 and "version 0.2.3" in capsys.readouterr().out
    channel = fresh_name("asm-flash")
    boards = [EmulatedModule(f"m{k}", k, settings=Settings(), interface="virtual", channel=channel) for k in (1, 2, 3)]
    watcher = Node("watcher", CanTransport(99, interface="virtual", channel=channel))
    try:
        assert boards[0].bus is boards[1].bus is boards[2].bus, "one bus for the boards of a channel (a backplane)"
        assert wait_until(lambda: {"m1", "m2", "m3"} <= set(watcher.discover()), timeout=30)
        code = main(["--robot", f"virtual:{channel}", "--modules", "1,3", str(image)])
        out, err = capsys.readouterr()
        assert code == 0, (out, err)
        assert "m1: updated (0.1.0 -> 0.2.3)" in out and "m3: updated (0.1.0 -> 0.2.3)" in out, out
        assert "m2" not in out and "100.0%" in err, (out, err)
        assert [b.firmware_version for b in boards] == [0x000203, 0x000100, 0x000203]
        assert main(["--robot", f"virtual:{channel}", "--modules", "9", "--discover", "0.5", str(image)]) == 1
        assert "m9: not on the bus" in capsys.readouterr().err
        not_an_image = tmp_path / "junk.bin"
        not_an_image.write_bytes(b"\x7fELF" + bytes(300))  # the linked ELF given where its image belongs
        assert main(["--robot", f"virtual:{channel}", str(not_an_image)]) == 1
        assert "an ELF file, not an update image: make one with python -m asm_module" in capsys.readouterr().err
        not_an_image.write_bytes(b"junk" * 100)
        assert main(["--robot", f"virtual:{channel}", str(not_an_image)]) == 1
        assert "not an update image" in capsys.readouterr().err
        with pytest.raises(SystemExit):
            main(["--robot", f"virtual:{channel}", "--modules", "0,300", str(image)])
        assert [b.firmware_version for b in boards] == [0x000203, 0x000100, 0x000203], "nothing else written"
        assert main(["--robot", f"virtual:{channel}", str(image)]) == 0  # all: the modules, not the watcher tool
        out, err = capsys.readouterr()
        assert "updating m1, m2, m3 to" in out and "watcher" not in out, out
        assert err.rstrip().endswith("3 modules x " + str(check(image.read_bytes()).size) + " bytes"), err
        assert "100.0%" in err.splitlines()[-1], err
        assert [b.firmware_version for b in boards] == [0x000203] * 3
    finally:
        watcher.close()
        for board in boards:
            board.close()
