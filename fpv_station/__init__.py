"""fpv-station's one import namespace: `fpv_station.core`, `fpv_station.server`, ...

The packages' folders stay at the top of the source tree (core/, server/, web/, ...), as
the design card names them. An installed wheel maps them under this package
(pyproject.toml's package-dir), so nothing of ours takes a generic top-level name such as
`core` or `server` in site-packages. In a source checkout (`PYTHONPATH=.`) the same names
resolve through this package's search path, extended to the checkout's root: each
checkout imports its own code.
"""

from pathlib import Path

_HERE = Path(__file__).resolve().parent
# Installed, the sub-packages sit inside this folder and the path stays as it is; in a
# checkout they are this folder's siblings.
if not (_HERE / "core" / "__init__.py").is_file():
    __path__.append(str(_HERE.parent))
