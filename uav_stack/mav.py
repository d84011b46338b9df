"""The one place that imports pymavlink, set up for MAVLink 2 and a small dialect.

Import ``mavutil`` and ``mavlink`` from here, never from pymavlink directly, so every
process frames MAVLink 2 (message ids > 255) and loads the same dialect.

* ``MAVLINK20`` must be set before ``mavutil`` is imported, otherwise it frames MAVLink 1.
* The dialect is mrswarm's own (``uav_stack.dialect``): pymavlink's ``all`` (common, ArduPilot's
  messages, development) plus the ids PX4 1.16 sends that pymavlink lacks (EVENT and its kin),
  so a message from either autopilot parses as itself, never as ``UNKNOWN_<id>``. It costs about
  3 MB of RSS per process more than ``common``. ``MAVLINK_DIALECT`` set to one of pymavlink's
  own dialects overrides it.
* ``mavutil`` imports ``pymavlink.dialects.v10.all`` only so PyInstaller bundles it; that
  import alone costs about 4 MB of RSS per process, which matters when a swarm runs 50
  agents on one machine. We pre-register an empty module under that name; nothing in
  mavutil uses it.
* ``mavutil`` imports ``ssl`` at the top but uses it only for TLS TCP links, and the
  dialect imports ``hashlib`` only for MAVLink signing; through OpenSSL's libcrypto they
  cost several MB of RSS. If nothing has imported them yet, a stand-in module takes each
  one's place and imports the real one on the first attribute access (module
  ``__getattr__``, PEP 562), so TLS links and signing still work and every other agent
  process saves the memory. (``LazyLoader`` from the
  standard library cannot do this on Python 3.11: the ``import`` statement itself reads
  ``__spec__``, which loads the module.)
"""

from __future__ import annotations

import importlib
import os
import sys
import types

from uav_stack import dialect

os.environ["MAVLINK20"] = "1"
sys.modules.setdefault("pymavlink.dialects.v10.all", types.ModuleType("pymavlink.dialects.v10.all"))


class _Deferred(types.ModuleType):
    """Stands in for a module until one of its attributes is used."""

    def __getattr__(self, attr: str) -> object:
        real = sys.modules.get(self.__name__)
        if real is self or real is None:
            del sys.modules[self.__name__]
            real = importlib.import_module(self.__name__)
        return getattr(real, attr)


for _name in ("ssl", "hashlib"):
    if _name not in sys.modules:
        sys.modules[_name] = _Deferred(_name)

# After the stand-ins: the generated dialect imports hashlib. mavutil loads the dialect that
# MAVLINK_DIALECT names when it is imported. Ours is registered as pymavlink.dialects.v20.mrswarm
# first, and the variable is put back afterwards: a child process (MAVProxy, a test's tool) would
# look for a dialect of that name among pymavlink's own.
_asked = os.environ.get("MAVLINK_DIALECT")
if _asked in (None, dialect.NAME):
    dialect.load()
    os.environ["MAVLINK_DIALECT"] = dialect.NAME

from pymavlink import mavutil  # noqa: E402

if _asked is None:
    del os.environ["MAVLINK_DIALECT"]
mavlink = mavutil.mavlink
assert mavlink is not None, "pymavlink did not load a dialect"

__all__ = ["mavutil", "mavlink"]
