"""Type-check the source tree with mypy, under the import names an install gives it.

Installed, the top-level folders are packages of ``fpv_station`` (core/ is
``fpv_station.core``: pyproject.toml's package-dir). In a checkout,
``fpv_station/__init__.py`` extends its search path at run time, which mypy does not
follow. So this script lays the install's layout out as symbolic links in build/typecheck/
(``fpv_station/core`` -> ``core/``), runs mypy with pyproject.toml's [tool.mypy] settings
and prints every path as the file's own (``core/link.py``), so that an error points at
the file to edit.

    python tools/typecheck.py [mypy options]      (make lint runs it)
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

from mypy import api

ROOT = Path(__file__).resolve().parent.parent
# Relative to ROOT, as pyproject.toml's [tool.mypy] names it (mypy_path, files).
TREE = Path("build/typecheck")


def _link(link: Path, target: Path) -> None:
    """Point ``link`` at ``target`` by a relative symbolic link (the checkout may move)."""
    relative = os.path.relpath(target, link.parent)
    if link.is_symlink() and os.readlink(link) == relative:
        return
    if link.is_symlink() or link.exists():
        link.unlink()
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(relative)


def lay_out_packages() -> dict[str, str]:
    """Link every installed package to its folder; returns link prefix -> folder prefix."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    package_dir: dict[str, str] = pyproject["tool"]["setuptools"]["package-dir"]
    prefixes = {}
    for name, folder in package_dir.items():
        link = ROOT / TREE / Path(*name.split("."))
        if "." not in name:
            # The namespace package itself: its own folder holds only its __init__.py, the
            # sub-packages are linked beside it.
            _link(link / "__init__.py", ROOT / folder / "__init__.py")
        else:
            _link(link, ROOT / folder)
        prefixes[f"{link.relative_to(ROOT)}/"] = f"{folder}/"
    return prefixes


def main() -> int:
    os.chdir(ROOT)
    prefixes = lay_out_packages()
    out, err, status = api.run(sys.argv[1:])
    # Longest prefix first: fpv_station/core/ before fpv_station/.
    for link, folder in sorted(prefixes.items(), key=lambda kv: -len(kv[0])):
        out = out.replace(link, folder)
    sys.stdout.write(out)
    sys.stderr.write(err)
    return status


if __name__ == "__main__":
    sys.exit(main())
