"""Gaits: the gait file format, validation, control tables and the gait library (gaits/library/*.toml)."""

import os

os.environ.setdefault("MUJOCO_GL", "disable")
"""No MuJoCo rendering context: the studio draws in the browser and nothing here renders with MuJoCo, and loading
one (glfw, cffi) cost each process ~0.1 CPU-s of its start (a robot or studio process ~0.74 → ~0.64 CPU-s to import;
the suite starts a few hundred). A user's own MUJOCO_GL is kept."""
