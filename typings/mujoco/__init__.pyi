"""The slice of MuJoCo's compiled API the studio calls, typed for the checker.

mujoco's bindings are a pybind11 extension without stubs, so a checker sees none of its names. This stub declares
the functions and enums the packages use with their real signatures; model and data fields stay ``Any`` (they are
numpy views whose shapes depend on the model), which is what the bindings return at run time.
"""

from enum import IntEnum
from typing import Any

import numpy as np

class mjtObj(IntEnum):
    mjOBJ_BODY = 1
    mjOBJ_JOINT = 3
    mjOBJ_GEOM = 5
    mjOBJ_ACTUATOR = 19

class mjtGeom(IntEnum):
    mjGEOM_PLANE = 0
    mjGEOM_HFIELD = 1
    mjGEOM_SPHERE = 2
    mjGEOM_CAPSULE = 3
    mjGEOM_CYLINDER = 5
    mjGEOM_BOX = 6
    mjGEOM_MESH = 7

class MjOption:
    timestep: float
    gravity: np.ndarray
    def __getattr__(self, name: str) -> Any: ...

class MjModel:
    nq: int
    nv: int
    nu: int
    nbody: int
    njnt: int
    ngeom: int
    opt: MjOption
    @staticmethod
    def from_xml_string(xml: str, assets: dict[str, bytes] | None = None) -> MjModel: ...
    @staticmethod
    def from_xml_path(filename: str, assets: dict[str, bytes] | None = None) -> MjModel: ...
    def __getattr__(self, name: str) -> Any: ...

class MjData:
    time: float
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    xpos: np.ndarray
    xquat: np.ndarray
    geom_xpos: np.ndarray
    geom_xmat: np.ndarray
    def __init__(self, model: MjModel) -> None: ...
    def __getattr__(self, name: str) -> Any: ...

def mj_name2id(m: MjModel, type: int, name: str) -> int: ...
def mj_id2name(m: MjModel, type: int, id: int) -> str | None: ...
def mj_step(m: MjModel, d: MjData, nstep: int = 1) -> None: ...
def mj_forward(m: MjModel, d: MjData) -> None: ...
def mj_kinematics(m: MjModel, d: MjData) -> None: ...
def __getattr__(name: str) -> Any: ...
