"""bench/_cpu.py, which bench/make_test.py --cpu uses to say where the suite's CPU goes: each kind of process the
suite starts is named apart, and a process's CPU is counted only from the sampler's start."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bench._cpu import CpuSampler, kind, report

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


@pytest.mark.parametrize(
    ("argv", "label"),
    [
        (["/usr/lib/chromium/chromium", "--type=gpu-process"], "chromium"),
        (["/work/.venv/bin/python", "-c", "import sys;exec(eval(sys.stdin.readline()))"], "pytest worker"),
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


def test_a_child_busy_while_sampled_is_counted_and_cpu_from_before_the_start_is_not():
    sampler = CpuSampler(interval=0.05).start()
    busy = subprocess.run(
        [sys.executable, "-c", "import time\nend = time.process_time() + 0.6\nwhile time.process_time() < end: pass"],
        timeout=60,
        check=True,
    )
    assert busy.returncode == 0
    # the child has exited: what the sampler saw of it last stands (its last 0.05 s may be missed)
    sampler.stop()
    cpu, count = sampler.totals()
    assert 0.3 <= cpu["python -c"] <= 1.5, report(cpu, count)
    assert count["python -c"] >= 1


def test_cpu_a_process_used_before_the_start_is_not_counted():
    burn_then_wait = "import sys, time\nend = time.process_time() + 0.6\nwhile time.process_time() < end: pass\n"
    burn_then_wait += "print('ready', flush=True)\nsys.stdin.read()"
    child = subprocess.Popen([sys.executable, "-c", burn_then_wait], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)  # fmt: skip
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "ready"
        sampler = CpuSampler(interval=0.05).start()
        assert child.stdin is not None
        child.stdin.close()
        child.wait(30)
        sampler.stop()
    finally:
        child.kill()
        child.wait(30)
    cpu, count = sampler.totals()
    assert cpu["python -c"] < 0.2, report(cpu, count)
