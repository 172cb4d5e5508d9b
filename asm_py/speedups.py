"""The C hot path (asm_py/_speedups.c, issue 31), or the pure-Python one when it is not built.

``make`` builds the extension through pip (setup.py; optional: a machine without a C compiler installs the package
without it). Without it — or with ``ASM_PURE_PYTHON=1`` in the environment — every transport and node runs the
pure-Python path, which the same tests cover (tests/transport/test_transport_conformance.py runs CAN both ways);
which one runs is logged once, when this module is first imported, and ``COMPILED`` says it.
"""

from __future__ import annotations

import logging
import os
from types import ModuleType

from .protocol import Message, Status

log = logging.getLogger("asm_py.speedups")


def _load() -> tuple[ModuleType | None, str]:
    if os.environ.get("ASM_PURE_PYTHON", "") not in ("", "0"):
        return None, "ASM_PURE_PYTHON is set"
    try:
        from . import _speedups  # type: ignore[attr-defined]  # built by setup.py; absent without a C compiler
    except ImportError as exc:
        return None, f"the extension is not built ({exc}; `make` builds it)"
    _speedups.setup(Message, Status.OK)
    return _speedups, ""


speedups, REASON = _load()
COMPILED = speedups is not None
"""Whether the C hot path is loaded."""
if COMPILED:
    log.debug("asm_py: the C hot path is loaded")
elif REASON == "ASM_PURE_PYTHON is set":
    log.info("asm_py: the pure-Python path runs (%s)", REASON)
else:
    log.warning("asm_py: the pure-Python path runs: %s", REASON)
