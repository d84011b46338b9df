"""Fixtures of the container tests: a reachable docker engine and the stack image.

Container tests never skip silently. Without a docker engine they **fail** with a message
that says how to get one (`scripts/test` installs docker.io and starts dockerd). Only an explicit
``MRSWARM_SKIP_DOCKER=1`` skips them, and pytest's summary (``-ra``) lists each skip.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest

from deploy.dockerutil import L_RUN, DockerUnavailable, client


def docker_client() -> Any:
    if os.environ.get("MRSWARM_SKIP_DOCKER") == "1":
        pytest.skip("container test skipped on request (MRSWARM_SKIP_DOCKER=1)")
    try:
        return client()
    except DockerUnavailable as exc:
        pytest.fail(f"container tests need a docker engine: {exc}", pytrace=False)


@pytest.fixture(scope="session")
def docker_image() -> str:
    """The stack image built from this checkout (rebuilt only if the source changed)."""
    import docker

    from deploy.images import BASE_TAG, ImageError, default_base, ensure_image

    cl = docker_client()
    base = default_base(cl)
    try:
        cl.images.get(base)
    except docker.errors.ImageNotFound:
        pytest.fail(f"no base image ({base}) and no registry: run `mrswarm deploy base-image` (debootstrap) "
                    f"or `scripts/test`, which makes {BASE_TAG}", pytrace=False)
    try:
        return ensure_image(base=base, log=lambda m: None).tag
    except ImageError as exc:
        pytest.fail(f"cannot build the stack image: {exc}", pytrace=False)


def containers_of(run: str) -> list[Any]:
    return client().containers.list(all=True, filters={"label": f"{L_RUN}={run}"})


@pytest.fixture
def no_leftovers() -> Iterator[None]:
    """Fails the test if it leaves any container or network labelled by a run behind."""
    cl = docker_client()
    before = {c.id for c in cl.containers.list(all=True, filters={"label": L_RUN})}
    nets_before = {n.id for n in cl.networks.list(filters={"label": L_RUN})}
    yield
    left = [c.name for c in cl.containers.list(all=True, filters={"label": L_RUN}) if c.id not in before]
    nets = [n.name for n in cl.networks.list(filters={"label": L_RUN}) if n.id not in nets_before]
    assert not left and not nets, f"left behind: containers {left}, networks {nets}"
