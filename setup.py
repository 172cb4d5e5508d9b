"""The C hot path (asm_py/_speedups.c over the C runtime's framing and header code), built by `make` through pip.

Optional: without a C compiler the package installs without it and asm_py.speedups logs that the pure-Python path
runs (the metadata is in pyproject.toml).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "asm_py._speedups",
            sources=["asm_py/_speedups.c", "firmware/src/wire.c", "firmware/src/can.c"],
            include_dirs=["firmware/include"],
            define_macros=[("Py_LIMITED_API", "0x030B0000")],
            py_limited_api=True,
            extra_compile_args=["-std=c11", "-O2", "-Wall", "-Wextra", "-Werror=implicit-function-declaration"],
            optional=True,
        )
    ]
)
