"""The Deploy tab checks a real robot against the edited gait's before deploying (gaits/compatible.py), in this
process without a browser."""

from __future__ import annotations

import pytest

from tests.helpers import wait_until

pytestmark = pytest.mark.timeout(120)


def test_a_real_robot_that_is_not_the_gaits_is_reported_before_deploy(studio, monkeypatch):
    """The Deploy tab on a real bus asks before deploying, and says first how the robot differs from the gait's (the
    robot here is the studio's simulated one, taken for real: its 8 modules answer as a bus's would)."""
    app = studio.app
    monkeypatch.setattr(type(studio), "simulated", property(lambda self: False))
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=30)
    app.deployer.on_deploy()
    assert "REAL robot?" in app.deployer.confirm.question.content
    assert "Not the robot" not in app.deployer.confirm.question.content  # the gait's own robot
    app.deployer.confirm.withdraw()
    app.doc.set_robot("modules", 10)  # a gait for a 10-module robot
    app.editor.after_edit()
    app.deployer.on_deploy()
    question = app.deployer.confirm.question.content
    assert "⚠ Not the robot this gait was made for: m9, m10 of the gait's 10 modules did not answer" in question
    app.deployer.confirm.withdraw()


def test_a_module_of_another_type_than_the_gait_describes_is_reported_before_deploy(studio, monkeypatch):
    """The simulated robot is built of the gait's module types, so its modules say them (module.type); taken for a
    real bus, a gait that describes m4 and m5 as another type is told so, and the log says what each module is."""
    from gaits.compatible import read_objects
    from gaits.model import LIBRARY, loads

    text = (LIBRARY / "caterpillar.toml").read_text(encoding="utf-8").replace(
        "module_size = 0.05\n", 'module_size = 0.05\ntype = "light"\n[robot.types.light]\n[robot.types.heavy]\n'
        "mass = 0.6\nids = [4, 5]\n", 1)  # fmt: skip
    app = studio.app
    assert studio.ensure_robot(loads(text)), "the simulated robot rebuilt of the gait's module types"
    assert wait_until(lambda: read_objects(app.link.lookup, ["m4", "m1"], "module.type", timeout=1.0)
                      == {"m4": "heavy", "m1": "light"}, timeout=60)  # fmt: skip
    monkeypatch.setattr(type(studio), "simulated", property(lambda self: False))
    assert wait_until(lambda: len(app.link.alive_modules()) == 8, timeout=30)
    app.doc.replace(loads(text.replace("heavy", "servo_v3")))
    app.editor.after_edit()
    app.deployer.on_deploy()
    question = app.deployer.confirm.question.content
    assert "m4 is module type heavy, the gait describes servo_v3 (robot.types.servo_v3)" in question, question
    assert "m5 is module type heavy" in question and "m3 is module type" not in question
    assert "type heavy" in app.deployer.log_html.content and "robot check: m4 is module type heavy" in (
        app.deployer.log_html.content)  # fmt: skip
    app.deployer.confirm.withdraw()
