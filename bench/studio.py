"""The preview's frame rate for a 32-module robot, seen from a browser, against the 60 frames/s the view aims for.

    .venv/bin/python bench/studio.py

`asm-studio` runs in its own process with a 32-module caterpillar (its robot, `asm-robot --sim`, in a child
process). For 8 s it counts:
- the scene updates a client that keeps up receives: a websocket client speaking viser's protocol, counting the
  messages that carry the modules' batched poses (what the server delivers);
- the frames Debian's Chromium draws with the page open (requestAnimationFrame callbacks, through Playwright).
  Headless Chromium on this VM renders WebGL in software (SwiftShader), so this is the no-GPU worst case.
Both are compared with 60/s, the first twice: with the preview playing, then in the Live view with the robot's 32
modules running the gait (deployed by a Zenoh client, as any tool would), its poses arriving from the robot
process. In this process, the cost of one SceneView.draw for the same robot is compared with the 1/60 s budget.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench._processes import Child, free_port
from gaits.model import LIBRARY, dumps, load
from web.document import GaitDocument
from web.viewer_client import camera_message, carries_poses

CHROMIUM = "/usr/bin/chromium"
MODULES = 32
SECONDS = 8.0


def gait_file(directory: str) -> Path:
    doc = GaitDocument(load(LIBRARY / "caterpillar.toml"))
    doc.set_robot("modules", MODULES)
    path = Path(directory) / "caterpillar32.toml"
    path.write_text(dumps(doc.gait()))
    return path


def draw_cost(path: Path) -> float:
    """Seconds per SceneView.draw of the 32-module robot (viser server in this process, nobody connected)."""
    import viser

    from web.preview import PreviewLoop
    from web.scene_view import SceneView

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    loop = PreviewLoop(load(path))
    try:
        view = SceneView(server, loop)
        while loop.shown() is None:
            time.sleep(0.01)
        view.draw()
        count, start = 0, time.perf_counter()
        while time.perf_counter() - start < 2.0:
            view._drawn = None  # draw even if the loop has not recorded a new frame meanwhile
            view.draw()
            count += 1
        return (time.perf_counter() - start) / count
    finally:
        loop.close()
        server.stop()


def studio(path: Path, endpoint: str, view: str = "preview") -> tuple[Child, int]:
    """`asm-studio` on ``path`` in its own process (its robot listening on ``endpoint``), once ready; and its port."""
    port = free_port()
    proc = Child("studio", "-m", "server.studio", "--gait", str(path), "--port", str(port), "--zenoh-listen", endpoint,
                   "--view", view)  # fmt: skip
    try:
        proc.ready("READY studio", timeout=60)
    except BaseException:
        proc.stop()
        raise
    return proc, port


def delivered(port: int) -> float:
    """Scene updates per second received by a websocket client that reads as fast as they come."""
    import viser
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None) as ws:  # type: ignore[list-item]
        ws.send(camera_message())  # a browser's first message: viser counts a client as connected from it on
        end = time.monotonic() + 2.0  # the scene is built and the preview plays
        while time.monotonic() < end:
            ws.recv(timeout=5)
        received, start = [], time.monotonic()
        while time.monotonic() - start < SECONDS:  # decoded afterwards: this client must not be the bottleneck
            received.append(ws.recv(timeout=5))
        elapsed = time.monotonic() - start
        return sum(1 for m in received if isinstance(m, bytes) and carries_poses(m)) / elapsed


def deploy_from_outside(path: Path, endpoint: str) -> None:
    """Deploy the gait to the studio's simulated modules and start them, as any Zenoh client can."""
    from asm_py import Node
    from asm_py.transport.zenoh import ZenohTransport
    from gaits.deploy import deploy

    client = Node("bench-client", ZenohTransport(connect=[endpoint]))
    try:
        deploy(client, load(path), timeout=10.0, deadline=20.0)  # staged, verified, activated, confirmed
        time.sleep(2.0)  # every module running, past its 1 s ramp
    finally:
        client.close()


def drawn_in_browser(port: int) -> float:
    """Frames per second Chromium draws with the page open while the preview plays."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"http://127.0.0.1:{port}")
        page.get_by_role("button", name=re.compile(r"^E-STOP")).wait_for(timeout=30_000)
        time.sleep(2.0)
        page.evaluate("window.__frames = 0; (function f() { window.__frames++; requestAnimationFrame(f); })()")
        start = time.monotonic()
        time.sleep(SECONDS)
        frames = page.evaluate("window.__frames")
        elapsed = time.monotonic() - start
        browser.close()
    return frames / elapsed


def main() -> None:
    with tempfile.TemporaryDirectory() as directory:
        path = gait_file(directory)
        cost = draw_cost(path)
        print(f"scene draw, {MODULES} modules: {cost * 1e3:.2f} ms per frame")
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        proc, port = studio(path, endpoint)
        try:
            received = delivered(port)
            print(f"websocket client, {MODULES} modules idle: {received:.1f} scene updates/s received")
            drawn = drawn_in_browser(port) if os.path.exists(CHROMIUM) else None
        finally:
            proc.stop()
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        proc, port = studio(path, endpoint, view="live")  # the Live view: the robot process's pose feed
        try:
            deploy_from_outside(path, endpoint)
            running = delivered(port)
            print(f"websocket client, Live view, {MODULES} modules running the gait: {running:.1f} scene updates/s")
        finally:
            proc.stop()
    print(f"ratio studio_scene_updates_{MODULES}_vs_60fps {received / 60:.2f} (target >= 0.9)")
    print(f"ratio studio_scene_updates_{MODULES}_running_vs_60fps {running / 60:.2f} (target >= 0.9)")
    print(f"ratio studio_draw_time_{MODULES}_vs_frame_budget {cost * 60:.3f} (target <= 0.25)")
    if drawn is None:
        print(f"no {CHROMIUM}: browser frame rate skipped (make test installs it)")
    else:
        print(f"ratio studio_browser_frames_{MODULES}_vs_60fps {drawn / 60:.2f} (target >= 0.9)")


if __name__ == "__main__":
    main()
