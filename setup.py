"""The compiled piece of mrswarm, optional: everything else is in pyproject.toml.

- ``uav_stack.fcu._dynamics``: the virtual FCU's multirotor step, and one vehicle's values read and targets
  written without numpy's indexing (uav_stack/fcu/_dynamics.c).

It is built when a C compiler and Python's headers are there (apt: gcc python3-dev; a pyenv or
python.org Python brings its headers). Without them the build skips it (``optional=True``) and
the same rules run in Python. A UAV reports which it runs in its status file
(``virtual_fcu.dynamics`` in ``uav<N>.json``). Only C that pays stays (docs/performance.md).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "uav_stack.fcu._dynamics",
            ["uav_stack/fcu/_dynamics.c"],
            depends=["uav_stack/fcu/_pyfloat.h"],
            # no fused multiply-add: the same rounding as the Python step, so both fly alike
            extra_compile_args=["-O2", "-ffp-contract=off"],
            optional=True,
        ),
    ]
)
