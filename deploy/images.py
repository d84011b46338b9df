"""Images without a registry: a Debian base made with debootstrap, and the stack image.

* :func:`make_base_image`: ``debootstrap --variant=minbase --include=python3 bookworm`` into
  a temporary folder, trimmed (apt lists and caches, docs, man pages, locales), then
  ``docker import`` -> ``mrswarm-base:bookworm`` (Python 3.11). Skipped when present.
* :func:`build_wheelhouse`: ``pip wheel`` on the host: third-party wheels (pinned to the
  versions installed here when they are, so the image runs what the tests ran) into
  ``deps/``, the project wheel into ``project/``. The dependency set is cached by its hash.
* :func:`build_image`: ``deploy/Dockerfile`` with the wheelhouse as context (no network
  in the build), tagged ``mrswarm:<version>`` and labelled with a hash of the source, so
  :func:`ensure_image` rebuilds only when the code changed.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from deploy.dockerutil import DeployError

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = Path(__file__).resolve().parent / "Dockerfile"
BASE_TAG = "mrswarm-base:bookworm"
DEFAULT_MIRROR = "http://deb.debian.org/debian"
PACKAGES = ("mrswarm", "groundfloor", "swarmnet", "uav_stack", "discovery", "world", "deploy")
# Trimmed from the debootstrap tree: nothing at run time reads these.
TRIM = ("var/cache/apt", "var/lib/apt/lists", "usr/share/doc", "usr/share/man", "usr/share/info", "usr/share/locale",
        "var/cache/debconf/templates.dat-old", "var/log")


class ImageError(DeployError):
    """An image cannot be made; the message says what is missing and how to get it."""


def image_tag() -> str:
    from swarmnet.version import __version__

    return f"mrswarm:{__version__}"


def _client() -> Any:
    from deploy.dockerutil import client

    return client()


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# ---- base image -----------------------------------------------------------------------------------
def make_base_image(tag: str = BASE_TAG, suite: str = "bookworm", mirror: str = DEFAULT_MIRROR, force: bool = False,
                    log: Callable[[str], None] = _log) -> str:
    """Make a minimal Debian image with Python 3 by debootstrap + ``docker import`` (cached)."""
    import docker

    cl = _client()
    if not force:
        try:
            cl.images.get(tag)
            log(f"base image {tag} is present (use --force to remake it)")
            return tag
        except docker.errors.ImageNotFound:
            pass
    if os.geteuid() != 0:
        raise ImageError("debootstrap needs root: run `sudo mrswarm deploy base-image`")
    if shutil.which("debootstrap") is None:
        raise ImageError("debootstrap is not installed: apt-get install debootstrap")
    with tempfile.TemporaryDirectory(prefix="mrswarm-base-") as tmp:
        rootfs = Path(tmp) / "rootfs"
        log(f"debootstrap {suite} from {mirror} (a minute or two) ...")
        res = subprocess.run(["debootstrap", "--variant=minbase", "--include=python3", suite, str(rootfs), mirror],
                             capture_output=True, text=True)
        if res.returncode != 0:
            raise ImageError(f"debootstrap failed ({res.returncode}):\n{(res.stdout + res.stderr)[-2000:]}")
        for rel in TRIM:
            p = rootfs / rel
            if p.is_dir():
                for child in p.iterdir():
                    if child.is_dir() and not child.is_symlink():
                        shutil.rmtree(child)
                    else:
                        child.unlink()
            elif p.exists():
                p.unlink()
        ver = subprocess.run(["chroot", str(rootfs), "python3", "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                             capture_output=True, text=True).stdout.strip()
        if ver != "3.11":
            raise ImageError(f"{suite}'s python3 is {ver or 'missing'}; mrswarm's image needs Python 3.11 (use bookworm)")
        tar_path = Path(tmp) / "rootfs.tar"
        with tarfile.open(tar_path, "w") as tar:
            for child in sorted(rootfs.iterdir()):
                tar.add(child, arcname=child.name)
        shutil.rmtree(rootfs)
        repo, _, version = tag.partition(":")
        log(f"docker import -> {tag}")
        cl.api.import_image_from_file(str(tar_path), repository=repo, tag=version or "latest", changes=[
            "ENV LANG=C.UTF-8",
            "CMD [\"python3\"]",
            f"LABEL org.mrswarm.image=base org.mrswarm.suite={suite}",
        ])
    cl.images.get(tag)  # raises if the import did not produce it
    return tag


# ---- wheelhouse ----------------------------------------------------------------------------------
# Left out of the image unless --full: only the runner uses them, on the host (analysis plots, the flight
# recorder's MCAP, the web map's server); a UAV container never imports them.
IMAGE_EXCLUDES = ("matplotlib", "mcap", "websockets")


def project_requirements(root: Path = ROOT, full: bool = False) -> list[str]:
    """The project's runtime dependencies, pinned to the versions installed here if any."""
    deps = tomllib.loads((root / "pyproject.toml").read_text())["project"]["dependencies"]
    out = []
    for d in deps:
        name = re.split(r"[<>=!~ ;\[]", d, maxsplit=1)[0]
        if not full and name.lower() in IMAGE_EXCLUDES:
            continue
        try:
            out.append(f"{name}=={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            out.append(d)
    return out


def source_hash(root: Path = ROOT) -> str:
    """Hash of what goes into the project wheel (package sources + pyproject)."""
    h = hashlib.sha256()
    files = [root / "pyproject.toml"] + sorted(p for pkg in PACKAGES for p in (root / pkg).rglob("*.py"))
    for f in files:
        h.update(str(f.relative_to(root)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _pip(args: list[str], log: Callable[[str], None]) -> None:
    cmd = [sys.executable, "-m", "pip", "--disable-pip-version-check", *args]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode != 0:
        raise ImageError(f"{' '.join(cmd)} failed:\n{(res.stdout + res.stderr)[-3000:]}")


# what the wheel's build copy of the checkout leaves out: never a name a package of the wheel has (a
# "results" pattern once dropped mrswarm/results from the image); benchmarks/ goes whole, results and all;
# compiled modules (*.so) an older checkout built: the wheel has none
WHEEL_SOURCE_IGNORE = (".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache", "benchmarks",
                       "tests", "*.so")


def build_wheelhouse(out: Path, root: Path = ROOT, full: bool = False, log: Callable[[str], None] = _log) -> Path:
    """``out/deps`` (cached by the requirement set) and ``out/project`` (rebuilt every time)."""
    reqs = project_requirements(root, full)
    deps, project = out / "deps", out / "project"
    stamp = deps / "requirements.txt"
    want = "\n".join(reqs) + "\n"
    if not (stamp.exists() and stamp.read_text() == want and any(deps.glob("pip-*.whl"))):
        log(f"pip wheel: {len(reqs)} dependencies -> {deps}")
        if deps.exists():
            shutil.rmtree(deps)
        deps.mkdir(parents=True)
        _pip(["wheel", "--quiet", "--only-binary=:all:", "--wheel-dir", str(deps), *reqs, "pip"], log)
        stamp.write_text(want)
    if project.exists():
        shutil.rmtree(project)
    project.mkdir(parents=True)
    log(f"pip wheel: mrswarm -> {project}")
    with tempfile.TemporaryDirectory(prefix="mrswarm-wheel-") as tmp:
        # build from a copy so setuptools' build/ and egg-info never land in the work tree
        src = Path(tmp) / "src"
        shutil.copytree(root, src, ignore=shutil.ignore_patterns(*WHEEL_SOURCE_IGNORE))
        env = dict(os.environ, SOURCE_DATE_EPOCH="315532800")
        res = subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "wheel", "--quiet", "--no-deps",
                              "--wheel-dir", str(project), str(src)],
                             capture_output=True, text=True, env=env)
        if res.returncode != 0:
            raise ImageError(f"building the mrswarm wheel failed:\n{(res.stdout + res.stderr)[-3000:]}")
    for whl in deps.glob("pip-*.whl"):
        shutil.copy2(whl, project / whl.name)
    return out


# ---- the stack image ---------------------------------------------------------------------------
@dataclass(frozen=True)
class ImageInfo:
    tag: str
    id: str
    size_mb: float
    source: str
    base: str


def build_image(tag: str | None = None, base: str | None = None, wheelhouse: Path | None = None, full: bool = False,
                log: Callable[[str], None] = _log) -> ImageInfo:
    """Build the stack image from a host-built wheelhouse (the build itself needs no network)."""
    import docker

    cl = _client()
    tag = tag or image_tag()
    base = base or default_base(cl)
    try:
        cl.images.get(base)
    except docker.errors.ImageNotFound:
        raise ImageError(f"base image {base} is not here and no registry is reachable: "
                         f"run `mrswarm deploy base-image` (debootstrap) or `docker load` one") from None
    wh = build_wheelhouse(wheelhouse or ROOT / "build" / "wheelhouse", full=full, log=log)
    shutil.copy2(DOCKERFILE, wh / "Dockerfile")
    (wh / ".dockerignore").write_text("Dockerfile\n.dockerignore\n")
    src = source_hash()
    log(f"docker build {tag} FROM {base}")
    # The dependency stage gets its own tag (per base and requirement set), so it stays in the
    # cache as a named image instead of a dangling one, and older ones can be dropped.
    deps_tag = "mrswarm-deps:" + hashlib.sha256(((wh / "deps" / "requirements.txt").read_text() + base).encode()).hexdigest()[:12]
    args = {"BASE_IMAGE": base, "SOURCE_HASH": src}
    try:
        cl.images.build(path=str(wh), tag=deps_tag, target="deps", buildargs=args, rm=True, forcerm=True,
                        network_mode="none", labels={"org.mrswarm.image": "deps"})
        cl.images.build(path=str(wh), tag=tag, buildargs=args, rm=True, forcerm=True, network_mode="none",
                        labels={"org.mrswarm.base": base})
    except docker.errors.BuildError as exc:
        tail = "".join(str(x.get("stream", x.get("error", ""))) for x in list(exc.build_log)[-30:])
        raise ImageError(f"docker build failed: {exc.msg}\n{tail}") from None
    _prune_old(cl, deps_tag)
    return image_info(tag)


def _prune_old(cl: Any, keep_deps: str) -> None:
    """Drop earlier builds: untagged stack images and dependency stages of other requirement sets."""
    try:
        cl.images.prune(filters={"dangling": True, "label": "org.mrswarm.image=stack"})
        for img in cl.images.list(name="mrswarm-deps"):
            if keep_deps not in img.tags:
                cl.images.remove(img.id, force=False)
        cl.images.prune(filters={"dangling": True, "label": "org.mrswarm.image=deps"})
    except Exception:  # noqa: BLE001 - pruning is housekeeping only
        pass


def default_base(cl: Any) -> str:
    """python:3.11-slim if it is here (pulled or loaded), else the debootstrap base."""
    import docker

    try:
        cl.images.get("python:3.11-slim")
        return "python:3.11-slim"
    except docker.errors.ImageNotFound:
        return BASE_TAG


def image_info(tag: str | None = None) -> ImageInfo:
    img = _client().images.get(tag or image_tag())
    labels = img.labels or {}
    return ImageInfo(tag=tag or image_tag(), id=img.id, size_mb=round(img.attrs["Size"] / 1e6, 1),
                     source=labels.get("org.mrswarm.source", ""), base=labels.get("org.mrswarm.base", ""))


def ensure_image(tag: str | None = None, base: str | None = None, log: Callable[[str], None] = _log) -> ImageInfo:
    """The stack image for the current source: reuse it if its source hash matches, else build."""
    import docker

    try:
        info = image_info(tag)
        if info.source == source_hash():
            return info
        log(f"{info.tag} was built from other sources; rebuilding")
    except docker.errors.ImageNotFound:
        pass
    return build_image(tag, base, log=log)


def describe(info: ImageInfo) -> dict[str, Any]:
    return json.loads(json.dumps(info.__dict__))
