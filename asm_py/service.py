"""The service: a routine with its own thread of control (paper section 2.2).

A *software* service overrides ``run``; ``start`` launches it on a thread of its own and returns at once. A
*hardware-style* service has no ``run``: ``start``/``stop``/``suspend``/``resume``/``reset`` only switch something,
through the ``on_*`` hooks. Both share the same state machine:

    stopped --start--> started+running <--suspend/resume--> started+suspended --stop--> stopped

``start`` on a started service raises ServiceError ("it must be stopped before it is started again"); ``reset``
raises ServiceError while running. Suspension takes effect where the routine cooperates — at ``checkpoint()`` and
``sleep()`` — which is where the paper's "pause the same process" can be honoured safely in Python.

``on_stop`` runs exactly once per start, whichever way the service ends: stopped, returned, or failed. For a
software service it runs in the service thread, after ``run``; for a hardware-style one, in the caller of ``stop``.
"""

from __future__ import annotations

import logging
import threading
from typing import Any, NamedTuple

from .clock import Clock, Monitor, _set_current_service
from .errors import AsmTimeout, ServiceError, ServiceStopped


class ServiceStatus(NamedTuple):
    """A service's flags, as one STATUS request reads them (the error as text: a remote one arrives as text)."""

    started: bool
    running: bool
    error: str | None


log = logging.getLogger("asm_py.service")


class Service:
    """Base of every service; see the module docstring."""

    def __init__(self, name: str, *, clock: Clock | None = None) -> None:
        self._name = name
        self._mon = Monitor(clock)
        self._started = False
        self._running = False
        self._stop_requested = False
        self._thread: threading.Thread | None = None
        self._blocked_on: Monitor | None = None
        self._last_error: BaseException | None = None

    # -- the interface of the paper -------------------------------------------------------------------------------

    @property
    def name(self) -> str:
        return self._name

    @property
    def clock(self) -> Clock:
        return self._mon.clock

    @property
    def started(self) -> bool:
        return self._started

    @property
    def running(self) -> bool:
        """Started and not suspended."""
        return self._started and self._running

    @property
    def last_error(self) -> BaseException | None:
        """The exception that ended the last run, if one did (also logged when it happened)."""
        return self._last_error

    def status(self, timeout: float | None = None) -> ServiceStatus:
        """started, running and the last error at once, as a client object reads them in one round trip."""
        error = self._last_error
        return ServiceStatus(self.started, self.running, None if error is None else repr(error))

    def start(self, *params: Any, wait: bool = True) -> None:
        """Start the service with ``params``; returns at once. ServiceError if already started.

        ``wait`` (here and on stop/suspend/resume/reset) exists for location transparency: a remote call returns
        before it is done unless it waits; a local one has always completed.
        """
        mon = self._mon
        with mon:
            if self._started or self._thread is not None:
                raise ServiceError(f"service {self._name!r} is already started; stop it before starting it again")
            self._started = True
            self._running = True
            self._stop_requested = False
            self._last_error = None
            thread = None
            if self._is_software():
                thread = threading.Thread(target=self._thread_main, args=params, name=f"asm:{self._name}", daemon=True)
            self._thread = thread
        try:
            self._starting(*params)
            self.on_start(*params)
        except BaseException:
            try:
                self._stopped()  # undoes _starting (an event-driven service's listener: kept, it handled firings twice)
            except Exception:
                log.exception("undoing the failed start of service %r failed", self._name)
            with mon:
                self._started = self._running = False
                self._thread = None
                mon.notify_all()
            raise
        if thread is not None:
            self.clock._thread_starting()
            thread.start()

    def stop(self, timeout: float | None = None, *, wait: bool = True) -> None:
        """Stop the service and wait (up to ``timeout`` seconds of its clock) for its thread to end.

        A blocking ASM call inside ``run`` is interrupted. Stopping a stopped service does nothing. Called from the
        service's own thread, it only asks: the thread ends when ``run`` returns.
        """
        mon = self._mon
        asked, thread = self._ask_to_stop()
        if not asked:
            return
        if thread is None:
            self._finish()
            return
        if thread is threading.current_thread():
            return
        with mon:
            ended = mon.wait_for(lambda: self._thread is not thread, timeout, interruptible=False)
        if not ended:
            raise AsmTimeout(f"service {self._name!r} did not stop within {timeout}s")
        if thread.ident is not None:
            thread.join()

    def request_stop(self) -> None:
        """Ask the service to stop and return at once, whatever it is doing: its thread ends at its next checkpoint,
        an event-driven service handles no further firing. For a caller that must never wait on the service (a
        module's e-stop path); ``stop`` waits for the end."""
        asked, thread = self._ask_to_stop()
        if asked and thread is None:
            self._finish()

    def _ask_to_stop(self) -> tuple[bool, threading.Thread | None]:
        """Set the stop flag and wake the service; (whether it was running, its thread)."""
        mon = self._mon
        with mon:
            thread = self._thread
            if not self._started or (thread is None and self._stop_requested):
                return False, thread
            self._stop_requested = True
            mon.notify_all()
            # Read after setting the flag: the service thread publishes _blocked_on before testing the flag.
            blocked = self._blocked_on
        if blocked is not None and blocked is not mon:
            with blocked:
                blocked.notify_all()
        return True, thread

    def suspend(self, *, wait: bool = True) -> None:
        """Pause the service; it holds at its next checkpoint or sleep. ServiceError if not started."""
        with self._mon:
            if not self._started:
                raise ServiceError(f"service {self._name!r} is not started; it cannot be suspended")
            if not self._running:
                return
            self._running = False
        self.on_suspend()

    def resume(self, *, wait: bool = True) -> None:
        """Continue a suspended service (the paper's ``continue``). ServiceError if not started."""
        mon = self._mon
        with mon:
            if not self._started:
                raise ServiceError(f"service {self._name!r} is not started; it cannot be resumed")
            if self._running:
                return
            self._resuming()
            self._running = True
            mon.notify_all()
        self.on_resume()

    continue_ = resume

    def reset(self, *, wait: bool = True) -> None:
        """Return the service to its initial condition; ServiceError while it is running."""
        with self._mon:
            if self._started and self._running:
                raise ServiceError(f"service {self._name!r} is running; stop or suspend it before reset")
            self._last_error = None
        self.on_reset()

    def join(self, timeout: float | None = None) -> bool:
        """Wait until the service has stopped by any means; False if ``timeout`` clock seconds passed first."""
        mon = self._mon
        with mon:
            return mon.wait_for(lambda: not self._started, timeout, interruptible=False)

    # -- what a routine calls from inside run ---------------------------------------------------------------------

    def checkpoint(self) -> bool:
        """Hold while suspended; return False once stop was asked (then ``run`` should return)."""
        mon = self._mon
        with mon:
            if not self._running and not self._stop_requested:
                mon.wait_for(lambda: self._running or self._stop_requested, None, interruptible=False)
            return not self._stop_requested

    def sleep(self, seconds: float) -> bool:
        """Sleep ``seconds`` on the service's clock; see :meth:`sleep_until`."""
        return self.sleep_until(self.clock.now() + seconds)

    def sleep_until(self, when: float) -> bool:
        """Sleep until clock time ``when``, holding while suspended; False as soon as stop is asked."""
        mon = self._mon
        clock = self.clock

        def done() -> bool:
            return self._stop_requested or (self._running and clock.reached(when))

        with mon:
            while not done():
                remaining = when - clock.now()
                mon.wait_for(done, remaining if remaining > 0 and self._running else None, interruptible=False)
            return not self._stop_requested

    @property
    def stop_requested(self) -> bool:
        return self._stop_requested

    # -- what subclasses write ------------------------------------------------------------------------------------

    def run(self, *params: Any) -> None:
        """The routine of a software service; a hardware-style service leaves it alone."""

    def on_start(self, *params: Any) -> None:
        """Called by ``start`` in the caller's thread, before any thread runs; an exception cancels the start."""

    def on_stop(self) -> None:
        """Called once per start when the service ends (see the module docstring)."""

    def on_suspend(self) -> None:
        """Called by ``suspend`` after the service is marked suspended."""

    def on_resume(self) -> None:
        """Called by ``resume`` after the service is marked running."""

    def on_reset(self) -> None:
        """Called by ``reset`` (never while running)."""

    # -- framework hooks for subclasses inside asm_py -------------------------------------------------------------

    def _starting(self, *params: Any) -> None:
        """Runs before ``on_start``."""

    def _resuming(self) -> None:
        """Runs under the monitor lock, just before the service is marked running again."""

    def _stopped(self) -> None:
        """Runs before ``on_stop``."""

    # -- internals ------------------------------------------------------------------------------------------------

    def _is_software(self) -> bool:
        return type(self).run is not Service.run

    def _thread_main(self, *params: Any) -> None:
        _set_current_service(self)
        try:
            self.run(*params)
        except ServiceStopped:
            pass
        except BaseException as exc:
            self._last_error = exc
            log.exception("service %r failed and stopped", self._name)
        finally:
            _set_current_service(None)
            try:
                self._finish()
            finally:
                self.clock._thread_exited()

    def _finish(self) -> None:
        """Run the end-of-service hooks, then mark the service stopped."""
        try:
            self._stopped()
            self.on_stop()
        except Exception:
            log.exception("on_stop of service %r failed", self._name)
        mon = self._mon
        with mon:
            self._started = self._running = False
            self._stop_requested = False
            self._thread = None
            mon.notify_all()

    def __repr__(self) -> str:
        state = "running" if self.running else "suspended" if self._started else "stopped"
        return f"<{type(self).__name__} {self._name!r} {state}>"
