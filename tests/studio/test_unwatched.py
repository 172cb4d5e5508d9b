"""A studio nobody watches spends nothing on drawing or on simulating its preview; the first browser to connect sees
the preview play on from where it waited, and the newest frame at once."""

from __future__ import annotations

import time

import pytest

from web.viewer_client import camera_message

from ..helpers import wait_until


@pytest.fixture
def unwatched_studio():
    from server.studio import Studio, StudioOptions

    studio = Studio(StudioOptions(port=0))
    try:
        yield studio
    finally:
        studio.close()


def test_nothing_is_simulated_or_drawn_until_a_browser_connects_then_the_newest_frame_is(unwatched_studio) -> None:
    import viser
    from websockets.sync.client import connect

    app = unwatched_studio.app
    assert wait_until(lambda: app.loop.held, timeout=20), "nobody watches: the preview waits"
    time.sleep(0.3)  # a step under way when the hold came is finished
    waiting = len(app.loop.frames)
    time.sleep(1.0)
    assert len(app.loop.frames) == waiting, "a preview nobody watches is not simulated"
    assert app.view._drawn is None and not app.watched()
    url = f"ws://127.0.0.1:{app.port}"
    with connect(
        url, origin=f"http://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], open_timeout=10
    ) as ws:
        ws.send(camera_message())  # viser counts a client as connected once its camera is known, as a browser sends it
        assert wait_until(app.watched, timeout=10)
        assert wait_until(lambda: len(app.loop.frames) > waiting + 30, timeout=20), "it plays once watched"
        assert wait_until(lambda: app.view._drawn is not None, timeout=10), "drawn once a browser came"
        drawn = app.view._drawn
        assert drawn is app.loop.shown() or drawn.time > 0.0
        ws.close()
    assert wait_until(lambda: not app.watched(), timeout=10)
    assert wait_until(lambda: app.loop.held, timeout=10), "the browser left: the preview waits again"
