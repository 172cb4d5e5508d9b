"""Transports carry ASM messages between named nodes: one base, one module per medium."""

from .base import Transport, check_name
from .memory import MemoryNetwork, MemoryTransport

__all__ = ["MemoryNetwork", "MemoryTransport", "Transport", "check_name"]
