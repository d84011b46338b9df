"""mrswarm's MAVLink dialect: one module that parses what ArduPilot and PX4 send.

pymavlink's ``common`` cannot parse ArduPilot's own messages (AHRS, EKF_STATUS_REPORT, SIMSTATE, ...)
nor the ids PX4 1.16 adds from its own ``common.xml`` (8 LINK_NODE_STATUS, 380
TIME_ESTIMATE_TO_TARGET, 410 EVENT, 411 CURRENT_EVENT_SEQUENCE, 412/413). ``mrswarm.xml`` beside this
file includes pymavlink's ``all.xml`` (common, ardupilotmega, development, ...) and adds those.

The Python module is generated from it with pymavlink's own generator (``mavgen``, a third of a
second) the first time a process needs it, and kept, byte-compiled, in a cache folder keyed by the
XML and pymavlink's version: beside this package when it is writable, else
``$XDG_CACHE_HOME/mrswarm`` (``~/.cache/mrswarm``), else the temporary folder. A file lock lets one
of many processes starting together generate it while the others wait; the file is written under a
temporary name and renamed, so no process ever imports half a module.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import sys
import types
import zlib
from collections.abc import Iterator
from pathlib import Path

from groundfloor.files import write_atomic

NAME = "mrswarm"
"""The dialect's name, as ``MAVLINK_DIALECT`` takes it: ``pymavlink.dialects.v20.mrswarm``."""

XML = Path(__file__).with_name("mrswarm.xml")


def _pymavlink_dir() -> Path:
    spec = importlib.util.find_spec("pymavlink")
    assert spec is not None and spec.origin is not None, "pymavlink is not installed"
    return Path(spec.origin).parent


def _key() -> str:
    # zlib's CRC, not hashlib: hashlib loads OpenSSL's libcrypto, several MB in every UAV process (uav_stack/mav.py)
    import pymavlink

    version = str(getattr(pymavlink, "__version__", ""))
    return f"{NAME}_{zlib.crc32(XML.read_bytes() + version.encode()):08x}"


def _cache_dirs() -> Iterator[Path]:
    yield Path(__file__).with_name("_generated")
    yield Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mrswarm"
    import tempfile

    yield Path(tempfile.gettempdir()) / f"mrswarm-{os.getuid()}"


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK | os.X_OK)


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    import fcntl

    with open(folder / ".lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _generate(target: Path) -> None:
    """mavgen from ``mrswarm.xml`` into ``target``, then byte-compiled (atomically both)."""
    import io
    import py_compile
    import shutil
    import tempfile

    from pymavlink.generator import mavgen, mavparse

    with tempfile.TemporaryDirectory(prefix="mrswarm-dialect-") as work:
        # mavgen resolves <include> beside the including file: pymavlink's XMLs go beside ours
        for xml in (_pymavlink_dir() / "dialects" / "v20").glob("*.xml"):
            shutil.copy(xml, work)
        shutil.copy(XML, work)
        out = Path(work) / "generated.py"
        opts = mavgen.Opts(str(out), wire_protocol=mavparse.PROTOCOL_2_0, language="Python3", validate=False)
        with contextlib.redirect_stdout(io.StringIO()):  # its progress lines would land in a UAV's log
            ok = mavgen.mavgen(opts, [str(Path(work) / XML.name)])
        if not ok:
            raise RuntimeError(f"mavgen could not generate the MAVLink dialect from {XML}")
        write_atomic(target, out.read_bytes())
    # the byte code too, whatever PYTHONDONTWRITEBYTECODE says: compiling 2.6 MB of source costs
    # each process about 100 MB of memory for a moment
    py_compile.compile(str(target), cfile=importlib.util.cache_from_source(str(target)), doraise=True)


def module_path() -> Path:
    """The generated module's file, generated first if no cache folder holds it yet."""
    key = _key()
    for folder in _cache_dirs():
        if (folder / f"{key}.py").is_file():
            return folder / f"{key}.py"
    for folder in _cache_dirs():
        if not _writable(folder):
            continue
        target = folder / f"{key}.py"
        with _locked(folder):
            if not target.is_file():
                _generate(target)
        return target
    raise RuntimeError("no writable folder for the generated MAVLink dialect (tried: "
                       + ", ".join(str(f) for f in _cache_dirs()) + ")")


def load() -> types.ModuleType:
    """The dialect module, registered as ``pymavlink.dialects.v20.mrswarm`` so that mavutil finds it."""
    import pymavlink.dialects.v20 as package  # mavutil walks the attributes down from pymavlink

    full = f"{package.__name__}.{NAME}"
    loaded = sys.modules.get(full)
    if loaded is not None:
        return loaded
    path = module_path()
    spec = importlib.util.spec_from_file_location(full, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[full] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[full]
        raise
    setattr(package, NAME, module)
    return module
