"""What every command line shares: argument types that refuse a bad value with a one-line usage error (exit 2),
and one way to end on a failure found while running (exit 1, ``prog: error: …``, never a traceback).

An argument is checked where argparse reads it, so ``--node-id 999`` or ``--port 99999`` is a usage error before
anything starts, rather than a traceback from deep inside a library or a server thread that dies while the process
keeps running. What can only fail at run time (a busy port, a missing CAN interface, an unwritable file) goes
through :func:`run`.
"""

from __future__ import annotations

import argparse
import faulthandler
import logging
import math
import os
import signal
import sys
import textwrap
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from .canbus.ids import MAX_NODE_ID, MIN_NODE_ID


def _number(text: str, kind: type) -> Any:
    try:
        value = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if kind is float and not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def bounded(kind: type, low: float | None = None, high: float | None = None, *, above: float | None = None,
            what: str = "") -> Callable[[str], Any]:  # fmt: skip
    """An argparse type: a number of ``kind`` in [low, high] (or > above), refused with the range otherwise."""

    def parse(text: str) -> Any:
        value = _number(text, kind)
        if (
            (low is not None and value < low)
            or (high is not None and value > high)
            or (above is not None and value <= above)
        ):
            lower = f"> {above:g}" if above is not None else (f">= {low:g}" if low is not None else "")
            upper = f"<= {high:g}" if high is not None else ""
            rule = " and ".join(part for part in (lower, upper) if part)
            raise argparse.ArgumentTypeError(f"{what or 'the value'} must be {rule}, not {text}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its own messages
    return parse


port = bounded(int, 0, 65535, what="a TCP port")
"""0..65535 (0: pick a free one)."""
node_id = bounded(int, MIN_NODE_ID, MAX_NODE_ID, what="a CAN node ID")
rate = bounded(float, above=0, high=1000, what="a rate in Hz")
positive_seconds = bounded(float, above=0, high=86_400, what="a time in seconds")
_bitrate = bounded(float, 10_000, 8_000_000, what="a CAN bit rate in bit/s")
frame_rate = bounded(float, 1, 60, what="a frame rate in frames per second")


def bitrate(text: str) -> int:
    """A CAN bit rate, 10 kbit/s .. 8 Mbit/s (``500000`` or ``5e5``)."""
    return int(_bitrate(text))


def can_channel(spec: str) -> dict[str, Any]:
    """``INTERFACE:CHANNEL`` (e.g. ``socketcan:can0``, ``virtual:bus0``) as python-can keyword arguments; the
    interface must be one python-can knows (its own list, plus the ``can.interface`` entry points, e.g. asm_sim)."""
    import can

    interface, sep, channel = spec.partition(":")
    if not sep or not interface or not channel:
        raise argparse.ArgumentTypeError(f"{spec!r} is not INTERFACE:CHANNEL, e.g. socketcan:can0")
    if interface not in can.VALID_INTERFACES:
        known = ", ".join(sorted(can.VALID_INTERFACES))
        raise argparse.ArgumentTypeError(f"unknown CAN interface {interface!r} (python-can knows: {known})")
    return {"interface": interface, "channel": channel}


def add_bus_arguments(cli: argparse.ArgumentParser) -> None:
    """The options of a process that bridges a CAN bus beside ``--can`` (``asm-bridge``, ``asm-robot``): its bit
    rate, FD, the bridge's node ID — one place, as python-can's ``add_bus_arguments`` gives its tools one."""
    cli.add_argument("--bitrate", type=bitrate)
    cli.add_argument("--fd", action="store_true", help="a CAN FD bus (with --can)")
    cli.add_argument("--node-id", type=node_id, default=254, help="the bridge's own CAN node ID (default 254)")


def input_file(text: str) -> Path:
    """An existing, readable file."""
    path = Path(text)
    if not path.is_file():
        raise argparse.ArgumentTypeError(f"{text}: {'not a file' if path.exists() else 'no such file'}")
    return path


def output_file(text: str) -> Path:
    """A file that can be created: its directory exists."""
    if not text:
        raise argparse.ArgumentTypeError("an empty file name")
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} is a directory, not a file name")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: the directory {path.parent} does not exist")
    return path


def summary(doc: str | None) -> str:
    """A command's ``--help`` description: its docstring's first paragraph, whole (its first line alone cut
    sentences such as asm-flash's in the middle)."""
    return textwrap.fill(" ".join((doc or "").strip().split("\n\n", 1)[0].split()), 78)


def describe(exc: BaseException) -> str:
    """An exception as one line for a person (Zenoh's errors carry the Rust source path they were raised at)."""
    text = str(exc) or type(exc).__name__
    for marker in (" at /", "\n"):
        text = text.split(marker, 1)[0]
    return text


SIGNAL_CHECK = 0.05
"""Seconds the main thread waits at a time for a stop (_StopEvent): the most a signal's stop waits to be seen."""


class _StopEvent(threading.Event):
    """An Event a signal handler can set without a lock, whose wait returns to the interpreter every
    ``SIGNAL_CHECK`` seconds.

    Python runs a signal's handler on the main thread between two bytecodes, also while that thread holds this
    event's lock: inside ``Event.wait``, or inside the first handler's ``set()`` when SIGINT and SIGTERM come
    together. A handler calling ``set()`` then waited for itself for ever (one of 12 busy servers in a fresh
    clone's run never ended). So a handler only raises a flag (``request``); ``wait`` and ``is_set`` read it, and
    the main thread's sliced wait sees it within a slice. The slices also serve the old cause: a main thread blocked
    in one long lock wait depends on the signal interrupting that wait, and a signal taken by another thread does
    not."""

    def __init__(self) -> None:
        super().__init__()
        self._requested = False

    def request(self, *_: object) -> None:
        """A signal handler: no lock taken (see the class)."""
        self._requested = True

    def is_set(self) -> bool:
        return self._requested or super().is_set()

    def clear(self) -> None:
        self._requested = False
        super().clear()

    def wait(self, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            if self._requested:
                return True
            left = SIGNAL_CHECK if deadline is None else min(SIGNAL_CHECK, deadline - time.monotonic())
            if super().wait(max(0.0, left)):
                return True
            if deadline is not None and time.monotonic() >= deadline:
                return self._requested


def stop_requested() -> threading.Event:
    """An event set by SIGTERM or SIGINT: a server command prints its ready line, waits on it, then closes in
    order (the main thread must call this: Python installs signal handlers there only).

    SIGUSR1 prints every thread's stack to standard error and goes on (faulthandler: it needs no Python thread to
    run, so it answers even when the interpreter is stuck, e.g. a thread holding the GIL while a native library
    waits for it): whoever finds a server that does not end on SIGTERM asks it where it is before killing it
    (server.child does)."""
    done = _StopEvent()
    faulthandler.register(signal.SIGUSR1, file=sys.stderr, all_threads=True)
    signal.signal(signal.SIGTERM, done.request)
    signal.signal(signal.SIGINT, done.request)
    return done


EXIT_GRACE = 4.0
"""Seconds a server command gets to close in order after SIGTERM before it exits anyway: a signal ends the process
within 5 s whatever the load (a flood of requests, a wedged module, a hung session close)."""

WATCHDOG_EXTRA = 1.0
"""Seconds after the grace that the native watchdog ends a process whose interpreter is stuck (close_and_exit)."""


def close_and_exit(close: Callable[[], None], prog: str, grace: float = EXIT_GRACE, *, code: int = 0) -> NoReturn:
    """Run ``close`` (a server command's orderly shutdown) for at most ``grace`` seconds, then end the process
    (exit ``code``, or 1 if closing failed or took too long: said, with where it was).

    The end is ``os._exit`` after flushing, not the interpreter's finalization: Zenoh's and foxglove-sdk's native
    threads can still call into Python then (a late callback), and a thread that wants the GIL during
    finalization is unwound through Rust frames, which aborts the process ("FATAL: exception not rethrown",
    SIGABRT: seen in a fresh-clone CI when a robot process was stopped). Everything that matters was closed in
    order by ``close``; the kernel closes the rest, and the children started die with this process.

    The grace is kept by this thread, which needs the interpreter: should a thread hold the GIL while a native
    library waits for it (a stopped robot once hung so under CI's load, killed after 10 s without a word), a
    native watchdog (faulthandler's) prints every thread's stack and exits 1 a second after the grace."""
    faulthandler.dump_traceback_later(grace + WATCHDOG_EXTRA, exit=True, file=sys.stderr)
    done = threading.Event()
    failed: list[BaseException] = []

    def closing() -> None:
        try:
            close()
        except BaseException as exc:  # said below; the exit code says it too
            failed.append(exc)
        finally:
            done.set()

    closer = threading.Thread(target=closing, name=f"{prog}-close", daemon=True)
    closer.start()
    if not done.wait(grace):
        frame = sys._current_frames().get(closer.ident or 0)
        where = "".join(traceback.format_stack(frame)[-6:]) if frame is not None else ""
        print(f"{prog}: closing took longer than {grace:g} s: exiting now; it was at\n{where}", file=sys.stderr,
              flush=True)  # fmt: skip
        code = 1
    elif failed:
        print(f"{prog}: closing failed: " + "".join(traceback.format_exception(failed[0])), file=sys.stderr, end="")
        code = 1
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe: nothing more can be said
            pass
    os._exit(code)


def reader_gone() -> int:
    """The end of a command whose output's reader went away (``… | head``): quietly, as a Unix filter ends. Standard
    output is pointed at /dev/null, so the interpreter's last flush at exit finds no closed pipe to complain of
    (Python's own recipe, "Note on SIGPIPE"); exit 1."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 1


def run(prog: str, body: Callable[[], int]) -> int:
    """Run a command's body; a failure found while running ends it with ``prog: error: …`` and exit 1."""
    import can
    import zenoh

    try:
        return body()
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return reader_gone()
    except (OSError, ValueError, RuntimeError, can.CanError, zenoh.ZError) as exc:
        print(f"{prog}: error: {describe(exc)}", file=sys.stderr)
        return 1


ZENOH_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws", "unixsock-stream")


def zenoh_endpoint(text: str) -> str:
    """A Zenoh locator such as ``tcp/127.0.0.1:7447`` or ``tls/[::1]:0``: a known protocol and, for IP links, a
    port 0..65535 (Zenoh itself accepts 99999 here and fails only when the session opens)."""
    protocol, sep, rest = text.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    if not sep or protocol not in ZENOH_PROTOCOLS or not address:
        raise argparse.ArgumentTypeError(f"{text!r} is not a Zenoh endpoint such as tcp/127.0.0.1:7447 "
                                         f"(protocols: {', '.join(ZENOH_PROTOCOLS)})")  # fmt: skip
    if protocol != "unixsock-stream":
        host, colon, number = address.rpartition(":")
        if not colon or not host or not number.isdigit() or not 0 <= int(number) <= 65535:
            raise argparse.ArgumentTypeError(f"{text!r}: an endpoint needs HOST:PORT with a port 0..65535")
    return text


def name(text: str) -> str:
    """A node or robot name as it appears in Zenoh keys (letters, digits, ``_ . -``; 1-64 characters)."""
    from .transport.base import check_name

    try:
        return check_name(text, "a name")
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def module_selection(text: str) -> tuple[int, ...] | str:
    """``--c-modules``: "odd", "even", "all", or module IDs separated by commas (1..254)."""
    if text in ("odd", "even", "all"):
        return text
    try:
        ids = tuple(sorted({int(part) for part in text.split(",")}))
    except ValueError:
        raise argparse.ArgumentTypeError(f"module IDs separated by commas, or odd, even, all; not {text!r}") from None
    if not all(1 <= i <= 254 for i in ids):
        raise argparse.ArgumentTypeError(f"module IDs are 1..254, not {text!r}")
    return ids
