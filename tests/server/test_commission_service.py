"""The robot process's commissioning service (server/commission_service.py) on a simulated robot whose boards are
a fresh batch (``--board-flash``): found by serial, each wiggled — the joint it sits on moves in the physics —
numbered along the chain by what moved, answering as m1..mN with module.info after; IDs kept across a robot restart
on the same flash folder; two boards with one ID reported; and every hostile request refused with its cause."""

from __future__ import annotations

import json
import logging
import shutil
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from asm_module.board_batch import BoardBatch
from asm_module.commission_link import CommissionError, commission
from asm_py.keys import RobotKeys
from asm_py.node import Node
from asm_py.remote import RemoteAttribute
from asm_py.transport.zenoh import ZenohTransport
from gaits.model import LIBRARY
from server.commission_service import ARRIVED
from server.robot import Robot, RobotOptions
from server.zenoh_args import ZenohOptions

from ..helpers import wait_until
from ..transports import free_port

pytestmark = [
    pytest.mark.timeout(600),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="make test installs gcc-arm-none-eabi"),
]
BOARDS = (1, 2, 3)
"""The chain positions that are emulated boards (the caterpillar's m4..m8 stay Python modules)."""


class Bench:
    """A robot process on ``folder`` and a tool's Zenoh node beside it."""

    def __init__(self, folder: Path | None, emulated: tuple[int, ...] = BOARDS) -> None:
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.robot = Robot(RobotOptions(sim=LIBRARY / "caterpillar.toml", emulated_modules=emulated, board_flash=folder,
                                        network=ZenohOptions(listen=(self.endpoint,))))  # fmt: skip
        try:
            self.client = Node("commission-test", ZenohTransport(connect=[self.endpoint]))
        except BaseException:
            self.robot.close()
            raise

    def ask(self, request: dict) -> dict:
        return commission(self.client.transport.session, "robot", request, timeout=180)  # type: ignore[attr-defined]

    def angle(self, position: int) -> float:
        assert self.robot.sim is not None
        return self.robot.sim.modules[position].driver.read().angle  # type: ignore[attr-defined]

    def close(self) -> None:
        self.client.close()
        self.robot.close()


@pytest.fixture
def bench(tmp_path) -> Iterator[Bench]:
    bench = Bench(tmp_path / "boards")
    try:
        yield bench
    finally:
        bench.close()


def _wiggled_position(bench: Bench, request: dict) -> tuple[int, dict, float]:
    """Wiggle as ``request`` says, sampling every joint meanwhile: the chain position whose joint moved most (the
    others moved less than two thirds as far: the chain shakes its neighbours a little), with the service's
    answer and how far that joint was held, as the physics has it: the median of its displacements while past
    half its swing."""
    rest = {p: bench.angle(p) for p in range(1, 9)}
    trace: dict[int, list[float]] = {p: [] for p in rest}
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            for p in rest:
                trace[p].append(abs(bench.angle(p) - rest[p]))
            time.sleep(0.01)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        answer = bench.ask(request)
    finally:
        done.set()
        sampler.join(5)
    swing = {p: max(t, default=0.0) for p, t in trace.items()}
    most = max(swing, key=lambda p: swing[p])
    assert swing[most] > 7.5 and all(s < swing[most] / 1.5 for p, s in swing.items() if p != most), swing
    away = sorted(v for v in trace[most] if v >= swing[most] / 2)
    return most, answer, away[len(away) // 2]


def _answered_its_travel(answer: dict, held: float) -> bool:
    """The wiggle's answer says the joint got (nearly) there: within ARRIVED and half a degree of the 15° asked —
    or, where the physics held the joint short, within a degree of where it was held. (A joint of the chain under
    load sits short of its goal: the physics had one overshoot to 16.7° in 50 ms and settle at 12.7-13.3° from
    where it started, after its neighbours' wiggles had moved the chain; the service reads it every 50 ms over
    ASM, missed the overshoot and answered 13.27° after SETTLED, a true answer 13.5 refused, in two CI runs.)"""
    return answer["moved"] >= min(15.0 - ARRIVED - 0.5, held - 1.0)


def _info(client: Node, name: str) -> dict | None:
    try:
        remote = client.lookup(name, "module.info", timeout=5)
        return remote.get(timeout=5) if isinstance(remote, RemoteAttribute) else None
    except Exception:  # not bridged yet
        return None


@pytest.mark.realtime  # the wiggled joint moves in the robot's real-time physics, judged on the wall clock: beside
# four workers the physics fell behind and the joint's last degrees came slower than SETTLED (12.5° of 15°, twice)
def test_fresh_boards_are_found_wiggled_numbered_along_the_chain_and_kept_across_a_restart(
    tmp_path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = tmp_path / "boards"
    bench = Bench(folder)
    try:
        listed = bench.ask({"op": "list"})
        serials = {BoardBatch(folder).serial(p).hex(): p for p in BOARDS}
        assert [m["serial"] for m in listed["modules"]] == sorted(serials), "in serial order, every time"
        assert all(m["id"] == 0 for m in listed["modules"]) and listed["conflicts"] == {}
        numbered = {}
        for module in listed["modules"]:  # the serials' order, not the chain's: the wiggle says where each sits
            position, answer, held = _wiggled_position(bench, {"op": "wiggle", "serial": module["serial"]})
            assert position == serials[module["serial"]]
            assert answer["id"] == 0 and answer["temporary"] == 199 and _answered_its_travel(answer, held), (
                answer,
                held,
            )
            numbered[module["serial"]] = position
        assert all(m["id"] == 0 for m in bench.ask({"op": "list"})["modules"]), "a wiggle leaves no ID behind"
        for serial, position in numbered.items():
            assert bench.ask({"op": "assign", "serial": serial, "id": position}) == {"serial": serial, "id": position}
        third = next(serial for serial, position in numbered.items() if position == 3)
        assert bench.ask({"op": "assign", "serial": third, "id": 0}) == {"serial": third, "id": 0}  # erased
        assert {m["serial"]: m["id"] for m in bench.ask({"op": "list"})["modules"]}[third] == 0
        bench.ask({"op": "assign", "serial": third, "id": 3})
        assert wait_until(lambda: all((_info(bench.client, f"m{p}") or {}).get("language") == 1 for p in BOARDS),
                          timeout=120)  # fmt: skip
        position, answer, _ = _wiggled_position(bench, {"op": "wiggle", "id": 2})  # numbered: wiggled by its ID
        assert position == 2 and answer["temporary"] is None
    finally:
        bench.close()
    bench = Bench(folder)  # the robot restarted on the same flash: the boards keep their IDs
    try:
        listed = bench.ask({"op": "list"})
        assert {m["serial"]: m["id"] for m in listed["modules"]} == numbered
        assert [m["id"] for m in listed["modules"]] == list(BOARDS), "numbered ones in the order of their IDs"
        assert wait_until(lambda: all(_info(bench.client, f"m{p}") for p in BOARDS), timeout=120)
    finally:
        bench.close()
    shutil.copyfile(folder / "board-2.flash", folder / "board-3.flash")  # two boards flashed alike: both ID 2
    caplog.set_level(logging.WARNING, logger="asm_robot")
    caplog.clear()
    bench = Bench(folder)  # ready once m1..m8 but m3 are bridged: the pair is one node (it waited 15 s, then warned)
    try:
        assert not [r for r in caplog.records if "bridged after" in r.getMessage()]
        assert sorted(bench.robot.bridge.bridged) == sorted(f"m{p}" for p in range(1, 9) if p != 3)
        clash = bench.ask({"op": "list"})["conflicts"]
        by_position = {p: BoardBatch(folder).serial(p).hex() for p in BOARDS}
        assert list(clash) == ["2"] and sorted(clash["2"]) == sorted([by_position[2], by_position[3]])
    finally:
        bench.close()


def test_hostile_requests_are_refused_with_their_cause(bench) -> None:
    session = bench.client.transport.session
    listed = bench.ask({"op": "list"})["modules"]
    serial = listed[0]["serial"]
    refusals = [
        ({"op": "assign", "serial": serial, "id": 254}, "node ID is 1..253"),
        ({"op": "assign", "serial": serial, "id": -1}, "node ID is 1..253"),
        ({"op": "assign", "serial": serial, "id": 2.5}, "whole number"),
        ({"op": "assign", "serial": serial, "id": True}, "whole number"),
        ({"op": "assign", "serial": serial, "id": 210}, "reserved"),  # a bridge alias: its Zenoh clients' ID
        ({"op": "assign", "serial": serial, "id": 5}, "taken by a module alive"),  # Python module m5
        ({"op": "assign", "serial": "00" * 12, "id": 9}, "no module with serial"),
        ({"op": "assign", "serial": "zz" * 12, "id": 9}, "24 hex digits"),
        ({"op": "assign", "serial": serial[:10], "id": 9}, "24 hex digits"),
        ({"op": "assign", "serial": ["x"], "id": 9}, "24 hex digits"),
        ({"op": "wiggle", "serial": serial, "degrees": 90}, "a wiggle moves 1-30°"),
        ({"op": "wiggle", "serial": serial, "degrees": float("nan")}, "a wiggle moves"),
        ({"op": "wiggle", "id": 0}, "node ID is 1..253"),
        ({"op": "wiggle", "id": 250}, "reserved"),  # at once (a review: 30 s, then "m250 did not answer")
        ({"op": "format"}, '{"op": "list"|"wiggle"|"assign"'),
        ({"op": "list", "pad": "x" * 2000}, "at most 1024 bytes"),
    ]
    for request, cause in refusals:
        with pytest.raises(CommissionError, match=cause.replace("|", r"\|").replace("(", r"\(")):
            bench.ask(request)
    for raw in (b"not json", b"[1, 2]", b"\xff\xfe"):
        reply = next(iter(session.get(RobotKeys("robot").commission(), payload=raw, timeout=30)))
        assert "error" in json.loads(reply.ok.payload.to_bytes())
    began = time.monotonic()  # a module that stops answering: its board closed, the wiggle's timeouts fire
    assert bench.robot.sim is not None
    bench.robot.sim.modules[1].close()
    gone = BoardBatch(Path(bench.robot.options.board_flash or "")).serial(1).hex()
    with pytest.raises(CommissionError, match="no module with serial"):
        bench.ask({"op": "wiggle", "serial": gone})
    assert time.monotonic() - began < 60
    assert gone not in {m["serial"] for m in bench.ask({"op": "list"})["modules"]}
    # one request at a time: a second one while a list runs is refused at once, not queued
    results: list[object] = []
    first = threading.Thread(target=lambda: results.append(bench.ask({"op": "list"})))
    first.start()
    try:
        assert wait_until(lambda: bench.robot.commission is not None and bench.robot.commission._running, 10)
        with pytest.raises(CommissionError, match=r"busy: another commissioning request \(list\)"):
            bench.ask({"op": "assign", "serial": serial, "id": 9})
    finally:
        first.join(120)
    assert isinstance(results[0], dict) and "modules" in results[0]


def test_while_the_robot_is_e_stopped_nothing_is_renumbered_erased_or_wiggled(bench) -> None:
    """Issue 28's second review (High): an ID given or erased resets the board, which released its latch, and a
    wiggle then moved the joint, during an e-stop. Refused, as a firmware update is, until the e-stop is released."""
    from asm_module.commission_link import CommissionError

    listed = bench.ask({"op": "list"})
    serial = listed["modules"][0]["serial"]
    assert wait_until(lambda: "m5" in bench.client.discover(), timeout=60)
    bench.client.estop("commissioning test")
    assert wait_until(lambda: bench.client.lookup("m5", "estop", timeout=5).peek() is True, timeout=30)
    before = [bench.angle(p) for p in BOARDS]
    wiggles = [{"op": "wiggle", "serial": serial}, {"op": "wiggle", "id": 5}]
    for request in [*wiggles, {"op": "assign", "serial": serial, "id": 1}, {"op": "assign", "serial": serial, "id": 0}]:
        with pytest.raises(CommissionError, match=r"e-stop is latched \(m\d.*release it first"):
            bench.ask(request)
    assert [bench.angle(p) for p in BOARDS] == pytest.approx(before, abs=0.5)
    assert all(m["id"] == 0 for m in bench.ask({"op": "list"})["modules"]), "no board was given an ID"
    for k in range(4, 9):  # the modules released; the service itself is not yet
        bench.client.lookup(f"m{k}", "estop", timeout=5).set(False)  # type: ignore[attr-defined]
    # issue 28's third review: a board without an ID runs no node and never latches, so on a batch of such boards
    # a lab-wide e-stop left nothing to refuse by; the service latches for them, until released
    for request in [*wiggles, {"op": "assign", "serial": serial, "id": 1}]:
        with pytest.raises(
            CommissionError,
            match=r"an e-stop was heard at \d\d:\d\d:\d\d from \S+: "
            r"commissi\S* and commissioning was not released since; .*release it first",
        ):
            bench.ask(request)
    assert wait_until(lambda: bench.robot.status.commissioning_stopped, timeout=10), "the robot's status says it"
    from web.robot_bar import describe_robot

    assert "commissioning stopped by an e-stop" in describe_robot(bench.robot.status)
    assert bench.ask({"op": "release"}) == {"released": True}
    assert bench.ask({"op": "release"}) == {"released": False}
    assert wait_until(lambda: not bench.robot.status.commissioning_stopped, timeout=10)
    bench.client.lookup("m5", "gait.service", timeout=5).start()  # type: ignore[attr-defined]  # a gait runs on m5
    assert wait_until(lambda: bench.client.lookup("m5", "gait.service", timeout=5).running, timeout=10)  # type: ignore[attr-defined]
    for request in [*wiggles, {"op": "assign", "serial": serial, "id": 1}]:
        with pytest.raises(CommissionError, match=r"a gait runs on m5; .*stop the gait first"):
            bench.ask(request)
    assert all(m["id"] == 0 for m in bench.ask({"op": "list"})["modules"])
    bench.client.lookup("m5", "gait.service", timeout=5).stop()  # type: ignore[attr-defined]
    assert wait_until(lambda: not bench.client.lookup("m5", "gait.service", timeout=5).running, timeout=10)  # type: ignore[attr-defined]
    outcome: list[object] = []  # an e-stop during a wiggle ends it: the board latched where it was, not moved back
    wiggling = threading.Thread(target=lambda: outcome.append(_asked(bench, {"op": "wiggle", "serial": serial})))
    start = [bench.angle(p) for p in BOARDS]
    wiggling.start()
    try:
        assert wait_until(lambda: max(abs(bench.angle(p) - a) for p, a in zip(BOARDS, start, strict=True)) > 3,
                          timeout=120), "the wiggle began"  # fmt: skip
        bench.client.estop("during a wiggle")
    finally:
        wiggling.join(120)
    assert isinstance(outcome[0], CommissionError) and "stopped: an e-stop was heard during the wiggle" in str(
        outcome[0]), outcome  # fmt: skip
    from web.link import RobotLink

    link = RobotLink(bench.client)  # the studio's E-STOP Release releases the service too
    try:
        assert link.release_commissioning() is True and link.release_commissioning() is False
    finally:
        link.close()


def _asked(bench: Bench, request: dict) -> object:
    try:
        return bench.ask(request)
    except Exception as exc:
        return exc


def test_a_board_batch_keeps_serials_and_refuses_a_damaged_one(tmp_path) -> None:
    batch = BoardBatch(tmp_path / "b")
    first = batch.serial(3)
    assert len(first) == 12 and BoardBatch(tmp_path / "b").serial(3) == first != batch.serial(4)
    (tmp_path / "b" / "board-3.serial").write_text("not a serial")
    with pytest.raises(ValueError, match=r"board-3\.serial: a board's serial is 24 hex digits"):
        batch.serial(3)
    for position in (0, 254, -1, "1", True):
        with pytest.raises(ValueError, match=r"chain position is 1\.\.253"):
            batch.serial(position)  # type: ignore[arg-type]


def test_boards_emulated_for_one_run_have_serials_of_their_own() -> None:
    # Issue 28's third review: without --board-flash every emulated board's serial was all zeros: the scan found
    # one module for two, and an ID given to that serial went to both.
    bench = Bench(None, (1, 3))  # no --board-flash: boards for this run only
    try:
        listed = bench.ask({"op": "list"})["modules"]
        assert sorted(m["id"] for m in listed) == [1, 3], listed
        assert len({m["serial"] for m in listed}) == 2 and "0" * 24 not in {m["serial"] for m in listed}, listed
    finally:
        bench.close()
