"""The Dockerfile and compose file agree with pyproject.toml and the settings (docker
cannot build here: no daemon; these catch what drifted before, e.g. a package not copied)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from fpv_station.server.settings import Settings

REPO = Path(__file__).resolve().parents[1]


def dockerfile() -> str:
    return (REPO / "Dockerfile").read_text()


def test_dockerfile_copies_every_installed_package():
    pyproject = tomllib.loads((REPO / "pyproject.toml").read_text())
    folders = pyproject["tool"]["setuptools"]["package-dir"].values()
    copied = set(re.findall(r"^COPY (\w+) \./\1$", dockerfile(), re.M))
    assert set(folders) == copied


def test_pyproject_lists_every_package_of_the_tree():
    """A package left out of pyproject.toml's list would be missing from the wheel."""
    setuptools = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]
    in_tree = {
        f"{name}.{'.'.join(init.parent.relative_to(REPO / folder).parts)}".rstrip(".")
        for name, folder in setuptools["package-dir"].items()
        for init in (REPO / folder).rglob("__init__.py")
    }
    assert set(setuptools["packages"]) == in_tree


def test_dockerfile_exposes_every_default_port_and_checks_health():
    s = Settings()
    ports = {s.server.port}  # the 3D panels' viser servers listen on loopback, behind it
    exposed = {
        int(p) for line in re.findall(r"^EXPOSE (.*)$", dockerfile(), re.M) for p in line.split()
    }
    assert ports == exposed
    assert "/api/health" in dockerfile() and "HEALTHCHECK" in dockerfile()


def test_dockerfile_runs_as_a_user_in_dialout_and_video():
    text = dockerfile()
    assert re.search(r"^USER fpv-station$", text, re.M)
    assert "--groups dialout,video" in text


def test_compose_publishes_the_same_ports_and_passes_devices():
    compose = (REPO / "deploy" / "compose.yaml").read_text()
    published = {int(p) for p in re.findall(r'"(\d+):\d+"', compose)}
    s = Settings()
    assert published == {s.server.port}
    for device in ("/dev/serial0", "/dev/video0", "/dev/video2"):
        assert f"{device}:{device}" in compose
    assert "restart: unless-stopped" in compose
