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
