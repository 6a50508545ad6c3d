"""The wheel installs beside another project's top-level `core` and `server`.

The wheel is built from this tree by the build backend pyproject.toml names, at the version
it requires, through the hook that builds it for `pip install .`, then installed into a fresh
virtual environment after a small package of the test's own that has top-level `core`
and `server` packages. There the installed station serves its pages, exports a Minari
dataset, and another process recovers the twin from that dataset alone (its stored
entry point), while the other package's `core` and `server` are still its own.

The environment's own site-packages holds only these two wheels. Their dependencies
(FastAPI, numpy, Gymnasium, Minari, ...) come from the running interpreter's
site-packages, added as a plain path, so nothing is downloaded but the build backend and
no import hook of an editable install runs there. Every process there runs with `-I`: no
PYTHONPATH, no current folder, so no checkout can stand in for what was installed.

Alone: `pytest -m wheel` (about a minute).
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import httpx
import pytest

from tests import synthetic as syn
from tests.known_flights import three_sorties
from tests.station_process import serve_station

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.wheel, pytest.mark.timeout(600)]

# The other project: generic names that a ground station must not take.
OTHER_FILES = {
    "core/__init__.py": 'NAME = "other-core"\n',
    "core/engine.py": 'def run() -> str:\n    return "the other engine"\n',
    "server/__init__.py": 'NAME = "other-server"\n',
}

# Run once the dataset is exported: one fresh interpreter, as a lab's would start.
INSTALLED = """
import importlib, importlib.metadata as md, json, sys
import gymnasium as gym
import minari
import numpy as np
ds = minari.load_dataset(sys.argv[1])
env = ds.recover_environment()  # the stored spec only: nothing of ours imported before
obs, _ = env.reset(seed=0)
obs, reward, *_ = env.step(np.zeros(4, np.float32))
# The registered id, through the module that registers it, in the same fresh process.
by_id = gym.make("fpv_station.twin.gym_env:fpv_station/TwinEnv-v0", task=1)
# The other project's names, by variable: no import line a rename would take for ours.
core, engine, server = (importlib.import_module(n) for n in ("core", "core.engine", "server"))
import fpv_station.server.app
files = md.distribution("fpv-station").files
print(json.dumps({
    "entry_point": ds.spec.env_spec.entry_point,
    "env_file": sys.modules[type(env.unwrapped).__module__].__file__,
    "obs": list(obs.shape), "reward": float(reward), "episodes": ds.total_episodes,
    "by_id": type(by_id.unwrapped).__name__,
    "top_level": sorted({f.parts[0] for f in files if f.parts[0] != ".."}),
    "other": [core.NAME, engine.run(), server.NAME],
    "ours": fpv_station.server.app.__file__,
}))
"""


def run(
    *args: str | Path, env: dict | None = None, cwd: Path | None = None, timeout: float = 300
) -> str:
    """Run a command without this checkout on its path (pip would see its metadata)."""
    base = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run(
        [str(a) for a in args],
        env={**base, **(env or {})},
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    assert done.returncode == 0, f"{args}: {done.stdout[-2000:]}\n{done.stderr[-4000:]}"
    return done.stdout


def source_copy(dst: Path) -> Path:
    """What a wheel is built from (pyproject's package folders), so the build writes no
    build/ or egg-info into the checkout and takes no stale files from one."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    dst.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, dst / name)
    skip = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in sorted(set(pyproject["tool"]["setuptools"]["package-dir"].values())):
        shutil.copytree(ROOT / folder, dst / folder, ignore=skip)
    return dst


def build_wheel(src: Path, out: Path) -> Path:
    """Our wheel, built from `src` as pip builds it in its isolated build environment:
    the backend pyproject.toml names, installed at the versions it requires into a
    folder of its own, then its PEP 517 `build_wheel` hook run in the source folder (pip
    asks the same backend first for its requirements and metadata, which the wheel
    holds too; each of those is one more interpreter with the backend imported)."""
    system = tomllib.loads((src / "pyproject.toml").read_text())["build-system"]
    backend = src.parent / "build-backend"
    run(sys.executable, "-m", "pip", "install", "-q", "--target", backend, *system["requires"])
    hook = (
        "import importlib, sys; sys.path.insert(0, sys.argv[1]); "
        "print(importlib.import_module(sys.argv[2]).build_wheel(sys.argv[3]))"
    )
    out.mkdir()
    # -S: no site-packages of ours, as in pip's isolated build environment.
    name = run(sys.executable, "-S", "-c", hook, backend, system["build-backend"], out, cwd=src)
    return out / name.splitlines()[-1].strip()


def other_wheel(out: Path) -> Path:
    """A wheel with top-level `core` and `server`, written directly (nothing to build)."""
    dist = "other_generic_names-1.0.dist-info"
    files = {
        **OTHER_FILES,
        f"{dist}/METADATA": "Metadata-Version: 2.1\nName: other-generic-names\nVersion: 1.0\n",
        f"{dist}/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\n"
        "Tag: py3-none-any\n",
    }
    record = []
    for name, text in files.items():
        digest = hashlib.sha256(text.encode()).digest()
        b64 = base64.urlsafe_b64encode(digest).rstrip(b"=").decode()
        record.append(f"{name},sha256={b64},{len(text.encode())}")
    record.append(f"{dist}/RECORD,,")
    path = out / "other_generic_names-1.0-py3-none-any.whl"
    with zipfile.ZipFile(path, "w") as z:
        for name, text in files.items():
            z.writestr(name, text)
        z.writestr(f"{dist}/RECORD", "\n".join(record) + "\n")
    return path


def make_venv(where: Path) -> tuple[Path, Path]:
    """A venv without pip (the running pip installs into it) and its site-packages."""
    run(sys.executable, "-m", "venv", "--without-pip", where)
    python = where / "bin" / "python"
    site = Path(run(python, "-I", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"))
    return python, Path(str(site).strip())


def test_the_wheel_installs_and_runs_beside_other_core_and_server(tmp_path):
    ours = build_wheel(source_copy(tmp_path / "src"), tmp_path / "wheels")
    assert ours.name.startswith("fpv_station-") and ours.suffix == ".whl"
    with zipfile.ZipFile(ours) as z:
        shipped = set(z.namelist())
    # Every source file of every package folder is in the wheel, pages and scenes too.
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    for package, folder in pyproject["tool"]["setuptools"]["package-dir"].items():
        for path in (ROOT / folder).rglob("*"):
            if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
                rel = path.relative_to(ROOT / folder).as_posix()
                assert f"{package.replace('.', '/')}/{rel}" in shipped

    python, site = make_venv(tmp_path / "venv")
    pip = [sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps"]
    run(*pip, "--no-index", other_wheel(tmp_path))  # the other project first: ours after it
    run(*pip, "--no-index", ours)
    deps = [p for p in sys.path if p.endswith(("site-packages", "dist-packages"))]
    (site / "runner_dependencies.pth").write_text("\n".join(deps) + "\n")

    # The console script, as a Pi runs it: the twin on the link, pages from the wheel.
    script = python.parent / "fpv-station"
    with serve_station(["--source", "sim"], python=python, launcher=("-I", str(script))) as st:
        health = httpx.get(f"{st.base}/api/health", timeout=10).json()
        index = httpx.get(f"{st.base}/", timeout=10)
        style = httpx.get(f"{st.base}/style.css", timeout=10)
    assert health["ok"] is True
    assert index.status_code == 200 and "<html" in index.text.lower()
    assert style.status_code == 200 and style.text == (ROOT / "web" / "style.css").read_text()

    tlog = syn.write_tlog(three_sorties(), tmp_path / "sorties.tlog")
    datasets = tmp_path / "minari"
    dataset_id = "fpv-station/wheel-task1/demos-v0"
    run(python, "-I", script, "export", tlog, "--format", "minari", "--task", "1",
        "--fps", "5", "--out", datasets, "--dataset-id", dataset_id, "--no-progress")  # fmt: skip
    env = {"MINARI_DATASETS_PATH": str(datasets)}
    got = json.loads(run(python, "-I", "-c", INSTALLED, dataset_id, env=env).splitlines()[-1])
    # The only importable name the station installs is its namespace.
    assert [n for n in got["top_level"] if not n.endswith(".dist-info")] == ["fpv_station"]
    assert got["other"] == ["other-core", "the other engine", "other-server"]
    assert Path(got["ours"]).is_relative_to(site)  # the installed copy, not a checkout
    assert got["entry_point"] == "fpv_station.twin.gym_env:TwinEnv"
    assert Path(got["env_file"]).is_relative_to(site)
    assert got["obs"] == [18] and got["episodes"] == 3 and got["by_id"] == "TwinEnv"
