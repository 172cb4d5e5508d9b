"""The Deploy tab checks a robot against the edited gait's before deploying (gaits/compatible.py, gaits.deploy's own
type check), in this process without a browser; the Modules tab shows the types the modules say."""

from __future__ import annotations

import re

import pytest

from gaits.compatible import read_objects
from gaits.model import LIBRARY, loads
from tests.helpers import wait_until

pytestmark = pytest.mark.timeout(120)

TYPED = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8").replace(
    "module_size = 0.05\n", 'module_size = 0.05\ntype = "light"\n[robot.types.light]\n[robot.types.heavy]\n'
    "mass = 0.6\nids = [4, 5]\n", 1)  # fmt: skip
"""The caterpillar of light modules with two heavy ones, m4 and m5."""


def _typed_robot(studio) -> None:
    """The studio's simulated robot rebuilt of TYPED's module types, its 8 modules saying them."""
    app = studio.app
    assert studio.ensure_robot(loads(TYPED)), "the simulated robot rebuilt of the gait's module types"
    assert wait_until(lambda: read_objects(app.link.lookup, ["m4", "m1"], "module.type", timeout=1.0)
                      == {"m4": "heavy", "m1": "light"}, timeout=60)  # fmt: skip
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=30)


def test_a_real_robot_that_is_not_the_gaits_is_reported_before_deploy(studio, monkeypatch):
    """The Deploy tab on a real bus asks before deploying, and says first how the robot differs from the gait's (the
    robot here is the studio's simulated one, taken for real: its 8 modules answer as a bus's would)."""
    app = studio.app
    monkeypatch.setattr(type(studio), "simulated", property(lambda self: False))
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=30)
    app.deployer.on_deploy()
    assert "REAL robot?" in app.deployer.confirm.asked
    assert "Not the robot" not in app.deployer.confirm.asked  # the gait's own robot
    app.deployer.confirm.withdraw()
    app.doc.set_robot("modules", 10)  # a gait for a 10-module robot
    app.editor.after_edit()
    app.deployer.on_deploy()
    question = app.deployer.confirm.asked
    assert "⚠ Not the robot this gait was made for: m9, m10 of the gait's 10 modules did not answer" in question
    app.deployer.confirm.withdraw()


def test_a_module_of_another_type_than_the_gait_describes_is_reported_before_deploy(studio, monkeypatch):
    """The simulated robot is built of the gait's module types, so its modules say them (module.type); taken for a
    real bus, a gait that describes m4 and m5 as another type is told so, and the log says what each module is."""
    app = studio.app
    _typed_robot(studio)
    monkeypatch.setattr(type(studio), "simulated", property(lambda self: False))
    app.doc.replace(loads(TYPED.replace("heavy", "servo_v3")))
    app.editor.after_edit()
    app.deployer.on_deploy()
    question = app.deployer.confirm.asked
    assert "m4 is module type heavy, the gait describes servo_v3 (robot.types.servo_v3)" in question, question
    assert "m5 is module type heavy" in question and "m3 is module type" not in question
    assert "type heavy" in app.deployer.log_html.content and "robot check: m4 is module type heavy" in (
        app.deployer.log_html.content)  # fmt: skip
    app.deployer.confirm.withdraw()


def test_a_simulated_robot_someone_else_started_is_checked_before_deploy(studio, monkeypatch):
    """issue 30's review, defect 1: a simulated robot the studio did not start (asm-robot --sim of another gait's
    robot) is not the studio's to rebuild, so its modules' types are checked before anything is sent, and the user
    asked, as for a real robot; a yes deploys knowingly."""
    from types import SimpleNamespace

    app = studio.app
    _typed_robot(studio)
    monkeypatch.setattr(studio, "own_robot", "someone-else")  # the robot is not the studio's own: not rebuilt
    assert app.deployer.page.simulated
    app.doc.replace(loads(TYPED.replace("ids = [4, 5]", "ids = [1, 2]")))  # the heavy modules moved to the tail
    app.editor.after_edit()
    app.deployer.on_deploy()
    asked = app.deployer.confirm.asked
    assert "⚠ Not the robot this gait was made for: m1 is module type light, the gait describes heavy" in asked
    assert [p.split(" is module type")[0] for p in asked.split(": ", 1)[1].split("; ")] == ["m1", "m2", "m4", "m5"]
    assert "staged" not in app.deployer.log_html.content and "robot check: m1 is module type light" in (
        app.deployer.log_html.content)  # fmt: skip
    app.deployer.confirm._on_click(SimpleNamespace(target=SimpleNamespace(value="Yes, deploy")))  # the user says yes
    assert "staged and verified on 8 modules. Start it now?" in app.deployer.confirm.asked
    app.deployer.confirm.withdraw()  # Cancel: the lease is released, nothing started


def test_a_yes_for_one_robot_never_deploys_to_another_the_page_switched_to(studio, monkeypatch):
    """issue 30's review (Low): "Yes, deploy" was tied to the question, not to the robot it asked about; the page
    switched to another robot meanwhile, a late yes deployed there, the mismatches it accepted taken for that one's."""
    from types import SimpleNamespace

    app = studio.app
    monkeypatch.setattr(type(studio), "simulated", property(lambda self: False))
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=30)
    app.deployer.on_deploy()
    assert "REAL robot?" in app.deployer.confirm.asked
    other = SimpleNamespace(robot="other-robot")  # the page now commands another robot's link
    monkeypatch.setattr(app.deployer.page, "_link", other)  # swapped (page.relink) before the question is withdrawn
    app.deployer.confirm._on_click(SimpleNamespace(target=SimpleNamespace(value="Yes, deploy")))
    log = app.deployer.log_html.content
    assert "not deployed: the yes was for robot robot, and the page now commands robot other-robot" in log, log
    assert "staged" not in log and not app.deployer.confirm.pending


def test_a_question_shows_what_a_robot_says_as_written_never_as_markup() -> None:
    """A module's type comes from the robot (a board's port sets any bytes): the question is markdown, which viser
    renders with raw HTML, so what it quotes is escaped (issue 30's review, defect 13: an <img> rendered)."""
    from types import SimpleNamespace

    from web.confirm import InlineConfirm

    handles: list[SimpleNamespace] = []

    def handle(*_: object, **__: object) -> SimpleNamespace:
        handles.append(SimpleNamespace(content="", visible=False, options=[], on_click=lambda callback: None))
        return handles[-1]

    gui = SimpleNamespace(add_markdown=handle, add_button_group=handle)
    confirm = InlineConfirm(gui, lambda callback: callback)
    said = "m4 is module type <img src=x onerror=alert(1)>, the gait describes **servo_v2** [link](http://x) a\\b"
    confirm.ask(said, "Yes", lambda: None)
    shown = handles[0].content
    assert confirm.asked == said and shown.startswith("**") and shown.endswith("**")
    assert not re.search(r"(?<!\\)[<>*\[\]()]", shown[2:-2]), shown  # no markup or tag character unescaped
    assert re.sub(r"\\(.)", r"\1", shown) == f"**{said}**", "each character is still there, escaped"


def test_the_modules_tab_shows_each_modules_type(studio):
    """issue 30's review, gap 16: the roster says what each module reports as its module.type, as written."""
    from web.modules_panel import roster_markdown

    app = studio.app
    _typed_robot(studio)
    app.modules._read()
    rows = {line.split("|")[1].strip(): line.split("|") for line in app.modules.roster_md.content.splitlines()
            if line.startswith("| m")}  # fmt: skip
    assert [rows[f"m{k}"][3].strip() for k in range(1, 9)] == ["light"] * 3 + ["heavy"] * 2 + ["light"] * 3
    table = roster_markdown(["m1", "m2"], {}, {}, {}, {"m1": "<b>x|y</b>"})
    assert "| m1 | — | \\<b\\>x\\|y\\</b\\> | — | — |" in table and "| m2 | — | — | — | — |" in table
