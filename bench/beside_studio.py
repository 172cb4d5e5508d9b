"""A 128-module robot beside the studio and a browser on the same two cores (issue 31): does it keep real time?

    .venv/bin/python bench/beside_studio.py            # the figure
    .venv/bin/python bench/beside_studio.py --modules 32

- ``robot_rtf_128_running_beside_studio``: ``asm-studio`` on a 128-module caterpillar, as ``make run`` starts it
  (its robot, ``asm-robot --sim``, a child process), its page open in Debian's Chromium (software WebGL here: no
  GPU) showing the **Live** view with the defaults a user gets (no URL parameters, no ``--max-fps``), the gait
  deployed by a Zenoh client and running; the robot's published real-time factor, the median of one reading a
  second over 10 s, after 4 s of settling. Target >= 1.0.

Also printed: the CPU each process took meanwhile (robot, studio, Chromium in all) and the frames Chromium drew a
second, so a miss says where the cores went.
"""

from __future__ import annotations

import argparse
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import psutil

from asm_py.node import Node
from asm_py.transport.zenoh import ZenohTransport
from bench._processes import Child, free_port
from bench.robot import Watch, resized
from gaits.deploy import deploy
from gaits.model import load

CHROMIUM = "/usr/bin/chromium"
SETTLE, SECONDS = 4.0, 10.0


def cpu(processes: list[psutil.Process]) -> float:
    total = 0.0
    for process in processes:
        try:
            times = process.cpu_times()
            total += times.user + times.system
        except psutil.NoSuchProcess:
            pass
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--modules", type=int, default=128)
    args = parser.parse_args()
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as folder:
        path = resized("caterpillar", args.modules, Path(folder))
        port, endpoint = free_port(), f"tcp/127.0.0.1:{free_port()}"
        studio = Child("studio", "-m", "server.studio", "--gait", str(path), "--port", str(port), "--zenoh-listen",
                       endpoint, "--recordings", folder, "--view", "live")  # fmt: skip
        client: Node | None = None
        watch: Watch | None = None
        try:
            studio.ready("READY studio", timeout=180)
            client = Node("bench", ZenohTransport(connect=[endpoint]))
            watch = Watch(client.transport.session)  # type: ignore[attr-defined]  # a ZenohTransport's session
            wanted = {f"m{i}" for i in range(1, args.modules + 1)}
            deadline = time.monotonic() + 120
            while not wanted <= set(client.discover()):
                if time.monotonic() > deadline:
                    raise SystemExit(f"only {len(client.discover())} of {args.modules} modules after 120 s")
                time.sleep(0.5)
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1366, "height": 768})
                page.goto(f"http://127.0.0.1:{port}/")
                page.get_by_role("button", name=re.compile(r"^E-STOP")).wait_for(timeout=60_000)
                deploy(client, load(path), timeout=10.0, deadline=60.0)
                time.sleep(SETTLE)
                root = psutil.Process(studio.popen.pid)
                robot = [p for p in root.children(recursive=True) if "server.robot" in " ".join(p.cmdline())]
                chromium = [p for p in psutil.Process().children(recursive=True) if "chrom" in p.name()]
                before = (cpu(robot), cpu([root]), cpu(chromium), time.monotonic())
                page.evaluate("window.__frames = 0; (function f() { window.__frames++; requestAnimationFrame(f); })()")
                factors = []
                for _ in range(int(SECONDS)):
                    time.sleep(1.0)
                    status = watch.status
                    factors.append(status.real_time_factor or 0.0 if status else 0.0)
                frames = page.evaluate("window.__frames")
                after = (cpu(robot), cpu([root]), cpu(chromium), time.monotonic())
                browser.close()
        finally:
            if watch is not None:
                watch.close()
            if client is not None:
                client.close()
            studio.stop()
    wall = after[3] - before[3]
    robot_cores, studio_cores, chromium_cores = ((a - b) / wall for a, b in zip(after[:3], before[:3], strict=True))
    factor = statistics.median(factors)
    print(f"# {args.modules} modules running, Live view in Chromium: real-time factor each second "
          f"{', '.join(f'{f:.2f}' for f in factors)}; cores: robot {robot_cores:.2f}, studio {studio_cores:.2f}, "
          f"Chromium {chromium_cores:.2f}; Chromium drew {frames / wall:.1f} frames a second")  # fmt: skip
    print(f"ratio robot_rtf_{args.modules}_running_beside_studio {factor:.2f} (target >= 1.0)")


if __name__ == "__main__":
    main()
