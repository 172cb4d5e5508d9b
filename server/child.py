"""A command run as a child process and waited for by its ready line.

Every command here prints one ``READY …`` line once it serves (docs/protocol.md, server/README.md), so whoever
starts one — a test, a bench, a lab script — waits for that line, never for a fixed time, and always stops the
child. One implementation for the suite and the benches (python-can keeps one ``Bus`` for all its callers too).
"""

from __future__ import annotations

import collections
import logging
import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

log = logging.getLogger(__name__)

STACKS_SECONDS = 2.0
"""Seconds a child that did not end on SIGTERM gets to print its threads' stacks before it is killed."""


_LOWEST_PORT = 20000
_recent: collections.deque[int] = collections.deque(maxlen=1000)
_random = random.SystemRandom()


def _ephemeral_low() -> int | None:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def free_port() -> int:
    """A TCP port free on loopback right now (bind and release): tests and benches never use a fixed port.

    Picked at random below the kernel's ephemeral range: a port from a port-0 bind is one the kernel hands out
    again to the next outgoing connection or port-0 bind of any process, and on a busy machine one did before the
    child bound it ("port … is in use"). Below the range only another free_port() can pick it, at random."""
    low = _ephemeral_low()
    for _ in range(1000 if low is not None and low - _LOWEST_PORT >= 2000 else 0):
        port = _random.randrange(_LOWEST_PORT, low or _LOWEST_PORT + 2000)
        if port in _recent:
            continue
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
        _recent.append(port)
        return port
    with socket.socket() as sock:  # no room below the range (or none free): the kernel's choice
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class ChildError(AssertionError):
    """The child ended, or did not print the awaited line in time; the message carries its output.

    An AssertionError, so a test that waits for a ready line fails (not errors) when the child does not come up."""


class Child:
    """``python *args``, its stdout and stderr collected line by line by a reader thread.

    ``prefix`` goes before python (``ip netns exec NS`` execs it); ``label`` names the child in errors; ``keep``
    bounds the lines kept in ``output`` (a studio's robot runs for days; a test keeps all for its failure message);
    ``pass_fds`` are file descriptors the child inherits (under the same numbers).
    """

    def __init__(
        self,
        *args: str,
        cwd: Path | None = None,
        prefix: tuple[str, ...] = (),
        label: str = "",
        keep: int | None = None,
        grace: float = 10.0,
        pass_fds: Sequence[int] = (),
    ) -> None:
        self.label = label or " ".join(args[:2])
        self.keep, self.grace = keep, grace
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.popen = subprocess.Popen([*prefix, sys.executable, *args], cwd=cwd, env=env, stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, text=True, pass_fds=pass_fds)  # fmt: skip
        self.output: list[str] = []
        self._changed = threading.Condition()
        self._read_lines = 0  # every line read so far; output holds the last len(output) of them
        self._waited = 0  # lines a wait has looked at: the next wait starts after them
        self._ended = False
        self._reader = threading.Thread(target=self._read, name=f"child-{self.popen.pid}", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            with self._changed:
                self.output.append(line)
                if self.keep is not None and len(self.output) > self.keep:
                    del self.output[: -self.keep]
                self._read_lines += 1
                self._changed.notify_all()
            log.debug("%s: %s", self.label, line.rstrip())
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def wait_for_line(self, prefix: str, timeout: float = 30.0) -> str:
        """The first line (after those earlier waits looked at) starting with ``prefix``; ChildError with the
        output if none comes in time or the child ends first."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while True:
                first = self._read_lines - len(self.output)  # the number of output[0]
                for number in range(max(self._waited, first), self._read_lines):
                    self._waited = number + 1
                    line = self.output[number - first].rstrip("\n")
                    if line.startswith(prefix):
                        return line
                if self._ended:
                    break
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise ChildError(f"{self.label}: no line starting with {prefix!r}; output:\n{''.join(self.output)}")
                self._changed.wait(remaining)
        self.popen.wait(5)
        raise ChildError(f"{self.label}: process exited ({self.popen.returncode}) before {prefix!r}:\n"
                         f"{''.join(self.output)}")  # fmt: skip

    ready = wait_for_line

    def kill(self) -> None:
        if self.popen.poll() is None:
            self.popen.kill()
        self.popen.wait(10)

    def stop(self) -> int:
        """Terminate politely, then kill after ``grace`` seconds; the exit code. A child still there after the
        grace is first asked for every thread's stack (SIGUSR1: asm_py.cli.stop_requested), so its output says
        where it hung."""
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(self.grace)
            except subprocess.TimeoutExpired:
                self.popen.send_signal(signal.SIGUSR1)
                try:
                    self.popen.wait(STACKS_SECONDS)
                except subprocess.TimeoutExpired:
                    pass
                self.popen.kill()
                self.popen.wait(10)
        self._reader.join(5)
        return self.popen.returncode


ROBOT_START_TIMEOUT = 60.0
"""Seconds a robot child may take to say READY (its imports and its modules, on a loaded machine)."""


class RobotChild(Child):
    """An ``asm-robot`` child process; it dies with this process (``--parent-pid``)."""

    def __init__(self, args: list[str], pass_fds: tuple[int, ...] = ()) -> None:
        self.args = args
        super().__init__("-m", "server.robot", "--parent-pid", str(os.getpid()), *args, label="the robot process",
                         keep=200, grace=6.0, pass_fds=pass_fds)  # fmt: skip
        try:
            self.wait_for_line("READY robot", timeout=ROBOT_START_TIMEOUT)
        except ChildError:
            self.stop()
            raise RuntimeError("the robot process did not start: " + "".join(self.output[-5:]).strip()) from None

    def exit_code(self) -> int | None:
        """The child's exit code once it has ended, else None."""
        return self.popen.poll()
