"""bench/_cpu.py, which bench/make_test.py --cpu uses to say where the suite's CPU goes: each kind of process the
suite starts is named apart, and a process's CPU is counted only from the sampler's start."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench._cpu import XDIST_WORKER, CpuSampler, kind

from ..helpers import wait_until

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


@pytest.mark.parametrize(
    ("argv", "label"),
    [
        (["/usr/lib/chromium/chromium", "--type=gpu-process"], "chromium"),
        (["/work/.venv/bin/python", "-u", "-c", XDIST_WORKER], "pytest worker"),
        (["/work/.venv/bin/python", "-c", "import sys; sys.stdin.read()"], "python -c"),
        (["/usr/lib/chromium/chromium --type=renderer --user-data-dir=/tmp/profile-abc --lang=en"], "chromium"),
        (["[kthreadd]"], "[kthreadd]"),
        (["/work/.venv/bin/python", "-m", "pytest", "-n", "3"], "pytest"),
        (["/work/.venv/bin/python", "-m", "server.robot", "--modules", "8"], "python -m server.robot"),
        (["/work/.venv/bin/python", "-u", "-m", "server.studio", "--port", "1"], "python -m server.studio"),
        (["/work/.venv/bin/python3.11", "-m", "basedpyright", "--level", "error"], "basedpyright"),
        (["/work/.venv/bin/python", "/work/.venv/bin/asm-studio", "--port", "1"], "asm-studio"),
        (["/work/.venv/bin/python", "bench/remote.py", "--serve", "tcp/127.0.0.1:1"], "python remote.py"),
        (["/work/.venv/bin/python", "-c", "print(1)"], "python -c"),
        (["/x/playwright/driver/node", "/x/playwright/driver/package/cli.js", "run-driver"], "playwright driver"),
        (["/bin/bash", "-c", "make test"], "bash"),
        ([], "?"),
    ],
)
def test_each_kind_of_process_is_named_apart(argv, label):
    assert kind(argv) == label


BURN = "import time\nend = time.process_time() + {seconds}\nwhile time.process_time() < end: pass\n"


def _state(pid: int) -> str:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return stat[stat.rfind(")") + 2]


def test_a_child_busy_while_sampled_is_counted():
    sampler = CpuSampler(interval=0.05).start()
    child = subprocess.Popen([sys.executable, "-c", BURN.format(seconds=0.6)])
    try:
        child.wait(60)
    finally:
        child.kill()
    sampler.stop()
    seconds, label = sampler.entries()[child.pid]
    assert label == "python -c"
    assert 0.3 <= seconds <= 1.5  # its last 0.05 s before it was reaped may be missed


def test_cpu_a_process_used_before_the_start_is_not_counted():
    code = BURN.format(seconds=0.6) + "print('ready', flush=True)\nimport sys\nsys.stdin.readline()"
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        sampler = CpuSampler(interval=0.05).start()
        time.sleep(0.3)  # sampled alive several times after the start
        assert child.stdin is not None
        child.stdin.close()
        child.wait(30)
        sampler.stop()
    finally:
        child.kill()
        child.wait(30)
    seconds, label = sampler.entries()[child.pid]
    assert label == "python -c"
    assert seconds < 0.2  # it used 0.6 CPU-s, all before the start


def test_a_child_that_exited_unreaped_keeps_its_kind_and_cpu():
    """A zombie has no command line left in /proc, only its CPU: it is still counted under what it was."""
    sampler = CpuSampler(interval=0.05).start()
    child = subprocess.Popen([sys.executable, "-c", BURN.format(seconds=0.3) + "time.sleep(0.3)"])
    try:
        assert wait_until(lambda: _state(child.pid) == "Z", timeout=30)  # exited, not yet waited for
        assert Path(f"/proc/{child.pid}/cmdline").read_bytes() == b""
        sampler.stop()  # its last look sees only the zombie
    finally:
        child.kill()
        child.wait(30)
    seconds, label = sampler.entries()[child.pid]
    assert label == "python -c"
    assert seconds >= 0.2
