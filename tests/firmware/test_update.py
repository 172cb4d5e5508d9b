"""Firmware update over the bus (issue 28, docs/protocol.md §12) on emulated boards running the board image behind
its bootloader: a good image is adopted and reports its version (a Python module on the same bus is skipped); a
corrupted image is refused before the swap; a reset in the middle of a write leaves the old image running and the
failed update reported; an image that never confirms itself is rolled back by the watchdog and the bootloader."""

from __future__ import annotations

import os
import shutil
import struct
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest

from asm_module._profile import FIRMWARE_STATES, IMAGE_CHUNK
from asm_module.firmware_image import ImageError, check
from asm_module.flash import Settings
from asm_py.errors import MessageTooLarge
from asm_py.node import Node
from asm_py.transport.can import CanTransport

from ..helpers import wait_until
from ..transports import fresh_name

pytestmark = [
    pytest.mark.timeout(300),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="the board image needs arm-none-eabi-gcc"),
]
OLD, NEW = 0x000100, 0x000200


@pytest.fixture
def bus() -> Iterator[tuple[str, Node]]:
    channel = fresh_name("fwupdate")
    # a board checking an image (a CRC over up to 64 KiB; on a real one, erasing a sector: 1-2 s) is silent a while
    tool = Node("tool", CanTransport(100, interface="virtual", channel=channel, missed_heartbeats=10))
    try:
        yield channel, tool
    finally:
        tool.close()


def _board(channel: str, node_id: int, settings: Settings):
    from asm_module.emulated import EmulatedModule

    return EmulatedModule(f"m{node_id}", node_id, settings=settings, interface="virtual", channel=channel)


def _new_image(pad_to: int = 0) -> bytes:
    from asm_module.emulated import versioned_image
    from asm_module.firmware_image import image_bytes

    return image_bytes(versioned_image(NEW), pad_to=pad_to)


def _status(tool: Node, name: str) -> dict[str, int]:
    return tool.lookup(name, "firmware.status", timeout=5).get(timeout=5)  # pyright: ignore[reportAttributeAccessIssue]


def _write(tool: Node, name: str, image: bytes, *, upto: int | None = None) -> None:
    target = tool.lookup(name, "firmware.image", timeout=5)
    for offset in range(0, len(image) if upto is None else upto, IMAGE_CHUNK):
        target.set(struct.pack("<I", offset) + image[offset : offset + IMAGE_CHUNK], timeout=10)  # pyright: ignore[reportAttributeAccessIssue]


def test_a_good_image_is_adopted_reports_its_version_and_a_python_module_is_skipped(bus) -> None:
    from asm_module.drivers import FakeDriver
    from asm_module.flasher import update_modules
    from asm_module.runtime import ModuleRuntime

    channel, tool = bus
    image = _new_image(pad_to=24 * 1024)  # padded (covered by the CRC): the board still runs the same code
    flashes = [Settings(), Settings()]
    boards = [_board(channel, k + 1, flashes[k]) for k in range(2)]
    python_node = Node("m3", CanTransport(3, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=3)
    seen: dict[str, list[int]] = {}
    try:
        assert wait_until(lambda: {"m1", "m2", "m3"} <= set(tool.discover()), timeout=30)
        assert [b.firmware_version for b in boards] == [OLD, OLD]
        report = update_modules(tool, ["m1", "m2", "m3"], image,
                                progress=lambda name, done, total: seen.setdefault(name, []).append(done))  # fmt: skip
        by_name = {r.module: r for r in report}
        for name in ("m1", "m2"):
            assert (by_name[name].outcome, by_name[name].old_version, by_name[name].new_version) == (
                "updated", OLD, NEW), by_name[name]  # fmt: skip
            assert seen[name] == sorted(seen[name]) and seen[name][-1] == len(image), "progress up to the whole image"
        assert by_name["m3"].outcome == "skipped" and "m3" not in seen, by_name["m3"]
        assert [b.firmware_version for b in boards] == [NEW, NEW]
        resets = [b.resets for b in boards]
        assert resets == [["the image asked for a reset (SYSRESETREQ)"]] * 2, resets
        status = _status(tool, "m1")
        assert (FIRMWARE_STATES[status["state"]], status["running"], status["other"]) == ("confirmed", NEW, OLD)
        assert tool.lookup("m1", "joint.goal", timeout=5) is not None, "the new image serves the module's objects"
    finally:
        for board in boards:
            board.close()
        runtime.close()
        python_node.close()
    again = _board(channel, 1, flashes[0])  # power cycled: the confirmed new image is the one booted
    try:
        assert again.firmware_version == NEW and again.fault is None
    finally:
        again.close()


def test_a_file_of_the_wrong_length_is_refused_saying_what_is_wrong() -> None:
    image = _new_image()
    with pytest.raises(ImageError, match=r"^70,000 bytes: an image is at most 65,536 bytes"):
        check(image + bytes(70_000 - len(image)))  # it said "the header says … (a multiple of 4, <= 65536)"
    with pytest.raises(ImageError, match=rf"the file has 20,000 bytes, its header says the image has {len(image):,}"):
        check(image[:20_000])
    with pytest.raises(ImageError, match="bytes appended"):
        check(image + bytes(8))


def test_a_corrupted_image_is_refused_before_the_swap_and_hostile_pieces_are_refused(bus) -> None:
    from asm_module.flasher import update_modules

    channel, tool = bus
    image = _new_image()
    corrupted = bytearray(image)
    corrupted[len(image) // 2] ^= 0x40  # one bit in the code; the header still claims the good CRC
    with pytest.raises(ImageError, match="damaged"):
        check(bytes(corrupted))
    with pytest.raises(ImageError):
        update_modules(tool, ["m1"], bytes(corrupted))  # the tool checks first: nothing is sent
    board = _board(channel, 1, Settings())
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        _write(tool, "m1", bytes(corrupted))  # past the tool's check, as a damaged transfer would be
        install = tool.lookup("m1", "firmware.install", timeout=5)
        with pytest.raises(ValueError):
            install.set(check(image).crc, timeout=10)
        status = _status(tool, "m1")
        assert (FIRMWARE_STATES[status["state"]], status["running"], status["received"]) == (
            "refused", OLD, len(image))  # fmt: skip
        target = tool.lookup("m1", "firmware.image", timeout=5)
        for piece, error in [
            (struct.pack("<I", 4096) + bytes(16), ValueError),  # not the next offset
            (struct.pack("<I", 0) + bytes(6), ValueError),  # not whole words
            (b"\x00\x00", ValueError),  # no offset
            (struct.pack("<I", 0) + bytes(IMAGE_CHUNK + 4), ValueError),  # over a piece (the object's capacity)
        ]:
            with pytest.raises(error):
                target.set(piece, timeout=10)
        _write(tool, "m1", image, upto=IMAGE_CHUNK)  # a fresh start from 0, one piece
        with pytest.raises(ValueError):
            install.set(check(image).crc, timeout=10)  # incomplete
        beyond = struct.pack("<I", 64 * 1024 - 8) + bytes(16)
        _write(tool, "m1", b"\xff" * (64 * 1024 - 8))
        with pytest.raises(MessageTooLarge):
            target.set(beyond, timeout=10)  # past the 64 KiB an image may have
        assert board.resets == [] and board.firmware_version == OLD and board.fault is None, "no swap, no reset"
        assert tool.lookup("m1", "joint.goal", timeout=5) is not None
    finally:
        board.close()


def test_a_latched_module_is_never_updated_so_its_e_stop_stays_latched(bus) -> None:
    """A review: an update during a latched e-stop was adopted, and the reset into it released the latch on every
    board. The board refuses both SETs with ESTOP while latched (an image written before the latch is not installed
    either); the tool says so and sends nothing."""
    from asm_module.flasher import update_modules
    from asm_py.errors import EstopLatched

    channel, tool = bus
    image = _new_image()
    board = _board(channel, 1, Settings())
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        _write(tool, "m1", image)  # written before the latch
        estop = tool.lookup("m1", "estop", timeout=5)
        estop.set(True, timeout=5)  # pyright: ignore[reportAttributeAccessIssue]
        assert estop.get(timeout=5)  # pyright: ignore[reportAttributeAccessIssue]
        with pytest.raises(EstopLatched):
            tool.lookup("m1", "firmware.install", timeout=5).set(check(image).crc, timeout=10)  # pyright: ignore[reportAttributeAccessIssue]
        with pytest.raises(EstopLatched):
            _write(tool, "m1", image, upto=IMAGE_CHUNK)
        [result] = update_modules(tool, ["m1"], image)
        assert (result.outcome, result.old_version, result.new_version) == ("refused", OLD, OLD), result
        assert "e-stop is latched" in result.detail, result
        time.sleep(0.5)  # a reset would follow an install by 0.1 s
        assert board.resets == [] and board.firmware_version == OLD and estop.get(timeout=5), "still latched, old image"  # pyright: ignore[reportAttributeAccessIssue]
    finally:
        board.close()


def test_a_reset_in_the_middle_of_a_write_leaves_the_old_image_running_and_reports_it(bus) -> None:
    from asm_module.flasher import update_modules

    channel, tool = bus
    image = _new_image()
    flash = Settings()
    board = _board(channel, 1, flash)
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        _write(tool, "m1", image, upto=len(image) // 2)
    finally:
        board.close()  # the power goes (the emulator stops mid-image)
    board = _board(channel, 1, flash)
    try:
        assert board.firmware_version == OLD and board.fault is None
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        status = _status(tool, "m1")
        assert (FIRMWARE_STATES[status["state"]], status["running"]) == ("interrupted", OLD), status
        (result,) = update_modules(tool, ["m1"], image)  # and the update can simply be run again
        assert (result.outcome, result.new_version) == ("updated", NEW), result
    finally:
        board.close()


def test_an_image_that_never_confirms_itself_is_rolled_back(bus, tmp_path: Path) -> None:
    from asm_module.elf import read_image
    from asm_module.emulator import register_image
    from asm_module.firmware_build import FIRMWARE, build_cortex_m4
    from asm_module.firmware_image import image_bytes
    from asm_module.flasher import update_modules

    source = (FIRMWARE / "port" / "stm32f4_update.c").read_text()
    confirm = "confirmed = !boot_log_append(LOG_CONFIRMED, slot, generation);"
    assert confirm in source
    broken = tmp_path / "stm32f4_update.c"
    broken.write_text(source.replace(confirm, "confirmed = 0; /* never */"))
    elf = tmp_path / "broken.elf"
    build_cortex_m4(elf, replace={"stm32f4_update.c": broken}, flags=("-DASM_FW_VERSION=0x000300u",))
    linked = read_image(elf)
    register_image(linked)
    image = image_bytes(linked)
    assert zlib.crc32(image[8:]) == check(image).crc and check(image).version == 0x000300
    channel, tool = bus
    board = _board(channel, 1, Settings())
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        (result,) = update_modules(tool, ["m1"], image, reboot_timeout=60)
        assert (result.outcome, result.old_version, result.new_version) == ("rolled_back", OLD, OLD), result
        assert board.resets == ["the image asked for a reset (SYSRESETREQ)", "the independent watchdog expired"]
        status = _status(tool, "m1")
        assert (FIRMWARE_STATES[status["state"]], status["other"]) == ("rolled_back", 0x000300)
        assert board.firmware_version == OLD and board.fault is None
        assert wait_until(lambda: len(board.resets) == 2 and board.milliseconds() > 6000, timeout=30), (
            "the old image, confirmed, feeds the watchdog: no further reset")  # fmt: skip
    finally:
        board.close()


def test_an_image_built_elsewhere_without_its_elf_runs_on_the_emulated_board(bus, tmp_path: Path) -> None:
    # A module builder's own build: the emulator has not its ELF (not registered, not in firmware/build). It found
    # the image's probe and fault handler in the image itself; before, the board stopped after the update's reset
    # ("the board runs an image the emulator has no ELF for") until the robot restarted.
    from asm_module.elf import read_image
    from asm_module.firmware_build import build_cortex_m4
    from asm_module.firmware_image import image_bytes
    from asm_module.flasher import update_modules

    elf = tmp_path / "elsewhere.elf"
    build_cortex_m4(elf, flags=("-DASM_FW_VERSION=0x000407u",))
    image = image_bytes(read_image(elf))
    channel, tool = bus
    board = _board(channel, 1, Settings())
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        (result,) = update_modules(tool, ["m1"], image, reboot_timeout=60)
        assert (result.outcome, result.old_version, result.new_version) == ("updated", OLD, 0x000407), result
        assert board.fault is None and board.firmware_version == 0x000407
        assert tool.lookup("m1", "estop", timeout=10).peek() is False  # it answers: the image runs
        tool.estop("the unknown image hears the e-stop")
        assert wait_until(lambda: tool.lookup("m1", "estop", timeout=10).peek() is True, timeout=20)
    finally:
        board.close()


def test_an_update_while_a_gait_runs_is_refused_before_anything_is_sent() -> None:
    # Issue 28's second review: the Modules tab updated all 8 boards of a walking caterpillar, each reset mid-step
    # and the robot fell where it stood. All or nothing: not one module is written to while any walks.
    from asm_module import FakeDriver, ModuleRuntime
    from asm_module.flasher import GaitRunning, update_modules
    from asm_py.transport.memory import MemoryNetwork, MemoryTransport
    from gaits.deploy import deploy, stop_all
    from gaits.model import LIBRARY, load

    network = MemoryNetwork()
    nodes = [Node(f"m{k}", MemoryTransport(network)) for k in range(1, 9)]
    runtimes = [ModuleRuntime(FakeDriver(), node=node) for node in nodes]
    tool = Node("tool", MemoryTransport(network))
    try:
        deploy(tool, load(LIBRARY / "caterpillar.toml"), timeout=1.0)
        names = [f"m{k}" for k in range(1, 9)]
        with pytest.raises(GaitRunning, match=r"not sent: a gait runs on m1, m2, .*m8; .*stop the gait first"):
            update_modules(tool, names, _new_image())
        tool.lookup("m1", "gait.service", timeout=5).stop()  # pyright: ignore[reportAttributeAccessIssue]
        assert wait_until(lambda: not runtimes[0].gait.started, timeout=10)
        with pytest.raises(GaitRunning, match=r"a gait runs on m2, .*m8"):  # m1 alone, the robot walking: refused
            update_modules(tool, ["m1"], _new_image())
        stop_all(tool)
        assert wait_until(lambda: not any(r.gait.started for r in runtimes), timeout=10)
        results = update_modules(tool, names, _new_image())  # stopped: it goes ahead (Python modules: skipped)
        assert [r.outcome for r in results] == ["skipped"] * 8
    finally:
        for runtime in runtimes:
            runtime.close()
        for node in [*nodes, tool]:
            node.close()


def _two_module_caterpillar():
    from gaits.model import LIBRARY, load
    from web.document import GaitDocument

    doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
    doc.set_robot("modules", 2)
    return doc.gait()


def test_a_board_takes_no_part_of_an_update_while_its_gait_runs_even_one_started_mid_update(bus) -> None:
    """Issue 28's third review: only the tool checked that no gait runs, so a gait started after that check (a
    group Start needs no lease) was under the update's reset. The board refuses image pieces and the install with
    LOCKED while its gait runs: the erase would stall its control loop, the reset drop its joint mid-step."""
    from asm_module.drivers import FakeDriver
    from asm_module.halts import read_halts
    from asm_module.runtime import ModuleRuntime
    from asm_py.errors import Locked
    from gaits.deploy import BROADCAST, deploy, stop_all
    from gaits.update import update_robot

    channel, tool = bus
    image = _new_image()
    board = _board(channel, 1, Settings())
    python_node = Node("m2", CanTransport(2, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=2)
    try:
        assert wait_until(lambda: {"m1", "m2"} <= set(tool.discover()), timeout=30)
        service = tool.lookup("m1", "gait.service", timeout=5)

        def stopped() -> bool:  # as the update reads the whole robot (m2 stopped a moment after m1 under load)
            return not read_halts(tool, ["m1", "m2"], 5).walking

        deploy(tool, _two_module_caterpillar(), timeout=3.0)
        assert service.running  # pyright: ignore[reportAttributeAccessIssue]
        with pytest.raises(Locked):
            _write(tool, "m1", image, upto=IMAGE_CHUNK)
        stop_all(tool)
        assert wait_until(stopped, timeout=10)
        _write(tool, "m1", image)  # written whole while nothing ran, then a gait started
        tool.group(BROADCAST).service("gait.service").start()
        assert wait_until(lambda: service.running, timeout=10)  # pyright: ignore[reportAttributeAccessIssue]
        with pytest.raises(Locked):
            tool.lookup("m1", "firmware.install", timeout=5).set(check(image).crc, timeout=10)  # pyright: ignore[reportAttributeAccessIssue]
        stop_all(tool)
        assert wait_until(stopped, timeout=10)
        started: list[bool] = []

        def start_once(module: str, done: int, total: int) -> None:
            if not started:  # a group Start from another tool, after the update's own check
                started.append(True)
                tool.group(BROADCAST).service("gait.service").start()

        by_name = {r.module: r for r in update_robot(tool, ["m1"], image, progress=start_once)}
        assert (by_name["m1"].outcome, by_name["m1"].new_version) == ("refused", OLD), by_name
        assert "gait was started on it during the update" in by_name["m1"].detail
        time.sleep(0.5)  # a reset would follow an install by 0.1 s
        assert board.resets == [] and board.firmware_version == OLD
        assert tool.lookup("m1", "gait.service", timeout=5).running, "it walks on"  # pyright: ignore[reportAttributeAccessIssue]
    finally:
        runtime.close()
        python_node.close()
        board.close()


def test_a_deploy_and_an_update_at_once_the_second_is_refused_naming_the_first(bus, monkeypatch) -> None:
    """Issue 28's third review: a deploy and an update started at the same instant both passed their checks and the
    update's resets felled the walking robot. The update holds every module's gait.lease as a deployer does, so the
    second of the two is refused, told who holds the robot, and nothing of it is sent."""
    from asm_module import flasher
    from asm_module.drivers import FakeDriver
    from asm_module.runtime import ModuleRuntime
    from gaits.calls import DeployError
    from gaits.deploy import deploy
    from gaits.update import RobotHeld, update_robot

    channel, tool = bus
    image = _new_image()
    gait = _two_module_caterpillar()
    board = _board(channel, 1, Settings())
    python_node = Node("m2", CanTransport(2, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=2)
    refusals: list[str] = []

    checked = flasher._gait_running

    def deploy_right_after_the_check(node: Node, modules, timeout: float) -> list[str]:
        walking = checked(node, modules, timeout)  # "no gait runs": the instant a deploy came in before
        try:
            deploy(tool, gait, timeout=3.0)
            refusals.append("deployed")
        except DeployError as exc:
            refusals.append(str(exc))
        return walking

    come_back = flasher._come_back

    def deploy_while_it_reboots(*args, **kwargs):
        time.sleep(0.3)  # m1 has reset (0.1 s after the install): its lease is gone with its RAM, m2's is held
        deploy_right_after_the_check(tool, [], 1.0)
        return come_back(*args, **kwargs)

    monkeypatch.setattr(flasher, "_gait_running", deploy_right_after_the_check)
    monkeypatch.setattr(flasher, "_come_back", deploy_while_it_reboots)
    try:
        assert wait_until(lambda: {"m1", "m2"} <= set(tool.discover()), timeout=30)
        by_name = {r.module: r for r in update_robot(tool, ["m1", "m2"], image)}
        monkeypatch.undo()
        assert len(refusals) == 2, refusals
        for refusal in refusals:  # before anything was sent, and while m1 rebooted: refused, the holder named
            assert "held by 'update by tool@" in refusal or "being deployed by 'update by tool@" in refusal, refusals
        assert (by_name["m1"].outcome, by_name["m1"].new_version) == ("updated", NEW), by_name
        assert not runtime.gait.started, "nothing of the deploy started"
        staged = deploy(tool, gait, start=False, timeout=3.0)  # a deploy holding the robot (waiting for Start)
        try:
            with pytest.raises(RobotHeld, match=r"not sent: .*lease"):
                update_robot(tool, ["m1"], _new_image(pad_to=20 * 1024))
            assert _status(tool, "m1")["received"] == 0, "not one piece sent"
        finally:
            staged.cancel()
        assert deploy(tool, gait, timeout=3.0).running, "the robot is free again after both"
    finally:
        runtime.close()
        python_node.close()
        board.close()


def test_a_long_host_name_does_not_stop_deploys_to_boards(bus, monkeypatch) -> None:
    """Found while reviewing the update's lease: a board keeps 32 bytes of a lease holder's name and refuses a longer
    one (VALUE_ERROR), and the holder was node@host:pid cut to 64, so on a host with a long name every deploy to a
    board failed with "value out of its domain". Every lease's holder fits the board's limit, host cut first."""
    from asm_module.drivers import FakeDriver
    from asm_module.runtime import ModuleRuntime
    from gaits import lease
    from gaits.deploy import deploy

    header = (Path(__file__).parents[2] / "firmware/include/asm/gait.h").read_text()
    assert f"#define ASM_LEASE_HOLDER {lease.HOLDER_BYTES}u" in header, "the Python limit is the board's"
    monkeypatch.setattr(lease.socket, "gethostname", lambda: "lab-workstation-03.robotics.example.org")
    channel, tool = bus
    board = _board(channel, 1, Settings())
    python_node = Node("m2", CanTransport(2, interface="virtual", channel=channel, watch_bus=False))
    runtime = ModuleRuntime(FakeDriver(), node=python_node, module_id=2)
    try:
        assert wait_until(lambda: {"m1", "m2"} <= set(tool.discover()), timeout=30)
        holder = lease.default_holder(tool)
        assert len(holder.encode()) <= lease.HOLDER_BYTES and holder.startswith("tool@lab-") and holder.endswith(
            f":{os.getpid()}"), holder  # fmt: skip
        assert lease.fit_holder("é" * 20) == "é" * 16, "cut at a character's end"
        assert set(deploy(tool, _two_module_caterpillar(), timeout=3.0).running) == {1, 2}
    finally:
        runtime.close()
        python_node.close()
        board.close()


def test_no_gait_starts_between_the_install_and_its_reset(bus) -> None:
    """Issue 28's fourth review (High): a group Start that came in the 0.1 s between an accepted install and its
    reset started the gait, and the reset dropped every such module mid-step (4 of 13 timed attempts). From the
    install on, the board refuses to start, resume or activate a gait (LOCKED; a group message: ignored)."""
    from asm_py.errors import Locked
    from gaits.deploy import BROADCAST

    channel, tool = bus
    image = _new_image()
    board = _board(channel, 1, Settings())
    try:
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        service = tool.lookup("m1", "gait.service", timeout=5)
        install = tool.lookup("m1", "firmware.install", timeout=5)
        _write(tool, "m1", image)
        install.set(check(image).crc, timeout=10)  # pyright: ignore[reportAttributeAccessIssue]
        tool.group(BROADCAST).service("gait.service").start()  # at once: the reset is 0.1 s away
        with pytest.raises(Locked):
            service.start(wait=True)  # pyright: ignore[reportAttributeAccessIssue]
        assert not service.running  # pyright: ignore[reportAttributeAccessIssue]  # nor did the group's start it
        assert wait_until(lambda: board.resets != [], timeout=30)
        assert board.firmware_version == NEW
        assert wait_until(lambda: "m1" in tool.discover(), timeout=30)
        assert not tool.lookup("m1", "gait.service", timeout=10).running, "it came back standing, as it went"  # pyright: ignore[reportAttributeAccessIssue]
    finally:
        board.close()
