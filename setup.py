"""The compiled pieces of mrswarm, all optional: everything else is in pyproject.toml.

- ``uav_stack.fcu._dynamics``: the virtual FCU's multirotor step, and one vehicle's values read and targets
  written without numpy's indexing (uav_stack/fcu/_dynamics.c);
- ``swarmnet._intake``: poses (edge-feed batches, direct poses) into the neighbour table (swarmnet/_intake.c);
- ``uav_stack._mavcodec``: MAVLink 2 frames of the FCU link's plain messages (uav_stack/_mavcodec.c).

They are built when a C compiler and Python's headers are there (apt: gcc python3-dev; a pyenv or
python.org Python brings its headers). Without them the build skips them (``optional=True``) and
the same rules run in Python. A UAV reports which it runs in its status file
(``virtual_fcu.dynamics``, ``virtual_fcu.mavlink`` and ``net.intake`` in ``uav<N>.json``).
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
        Extension(
            "swarmnet._intake",
            ["swarmnet/_intake.c"],
            extra_compile_args=["-O2", "-ffp-contract=off"],  # the same rounding as the Python rules
            optional=True,
        ),
        Extension(
            "uav_stack._mavcodec",
            ["uav_stack/_mavcodec.c"],
            depends=["uav_stack/_x25crc.h"],
            extra_compile_args=["-O2"],
            optional=True,
        ),
    ]
)
