"""asm_py — the Attribute/Service Model: attributes, services, events and triggers, event-driven services and phase
automata, with every timing on a Clock. This package is what a module runs: it imports neither viser nor mujoco."""

from .attribute import Attribute, CheckedAttribute
from .automaton import PeriodicAutomaton, PhaseAutomaton, PhaseState
from .clock import WALL_CLOCK, Clock, Monitor, SimClock, WallClock
from .codec import (
    BOOL,
    BYTES,
    FLOAT32,
    FLOAT64,
    INT8,
    INT16,
    INT32,
    INT64,
    STR,
    UINT8,
    UINT16,
    UINT32,
    UINT64,
    Codec,
    float_array,
    record,
)
from .codec_parse import codec_from_descriptor, parse_codec
from .eds import EventDrivenService
from .errors import (
    AsmError,
    AsmTimeout,
    EstopLatched,
    Locked,
    MessageTooLarge,
    ReadOnlyError,
    Refused,
    RemoteError,
    ServiceError,
    ServiceStopped,
    SimulationStalled,
)
from .event import ConditionTrigger, Event, ThresholdTrigger, TimerTrigger, Trigger
from .group import GroupAttribute, GroupPort, GroupService
from .node import Node
from .remote import RemoteAttribute, RemoteEvent, RemoteService
from .service import Service
from .transport import MemoryNetwork, MemoryTransport, Transport

__version__ = "0.1.0"

__all__ = [
    "Attribute", "CheckedAttribute", "EstopLatched", "Locked", "MessageTooLarge", "ReadOnlyError", "Refused",
    "PeriodicAutomaton", "PhaseAutomaton", "PhaseState", "WALL_CLOCK", "Clock", "Monitor",
    "SimClock", "WallClock", "BOOL", "BYTES", "FLOAT32", "FLOAT64", "INT8", "INT16", "INT32", "INT64", "STR",
    "UINT8", "UINT16", "UINT32", "UINT64", "Codec", "codec_from_descriptor", "float_array", "parse_codec",
    "record", "EventDrivenService", "AsmError", "AsmTimeout", "ServiceError", "ServiceStopped",
    "SimulationStalled", "ConditionTrigger", "Event", "ThresholdTrigger", "TimerTrigger", "Trigger", "Service",
    "RemoteError", "Node", "GroupPort", "GroupAttribute", "GroupService",
    "RemoteAttribute", "RemoteEvent", "RemoteService", "MemoryNetwork", "MemoryTransport", "Transport",
]  # fmt: skip
