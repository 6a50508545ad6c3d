"""The docs stay a reference a newcomer can trust: the README short with both commands on
top, every link and every named source file real, every route of the app in docs/API.md,
PERFORMANCE.md within its length."""

import re
from pathlib import Path

from fastapi.routing import APIRoute, APIWebSocketRoute

from fpv_station.server.app import create_app
from fpv_station.server.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [ROOT / "README.md", *DOCS]

LINK = re.compile(r"\]\(([^)\s]+)\)")
# A repository path in prose or code spans: at least one folder, a source or config file.
SOURCE_PATH = re.compile(
    r"(?<![\w./-])((?:[\w-]+/)*[\w.-]+\.(?:py|js|html|css|toml|md|yaml|service))(?![\w/])"
)


def test_readme_is_short_and_starts_with_both_commands():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 150, f"README.md has {len(lines)} lines; the rest belongs in docs/"
    top = "\n".join(lines[:10])
    assert "make run" in top and "make test" in top


def test_performance_is_a_reference_within_its_length():
    lines = (ROOT / "docs" / "PERFORMANCE.md").read_text().splitlines()
    assert len(lines) <= 400, f"docs/PERFORMANCE.md has {len(lines)} lines"


def test_every_relative_link_resolves():
    broken = []
    for page in PAGES:
        for target in LINK.findall(page.read_text()):
            if re.match(r"^[a-z]+:", target) or target.startswith("#"):
                continue
            path = target.split("#")[0]
            if not (page.parent / path).exists():
                broken.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not broken, broken


def _repo_files() -> list[str]:
    skip = {".git", ".venv", "node_modules", "build"}
    return [
        p.relative_to(ROOT).as_posix()
        for p in ROOT.rglob("*")
        if p.is_file() and not skip.intersection(p.relative_to(ROOT).parts)
    ]


def test_every_source_path_named_in_the_docs_exists():
    """A path is the repository's (`analysis/track.py`), or the tail of one as a listing or
    a sentence names it under its folder (`scenes/field.toml`, `track.py`); a bare name
    is checked for source files only."""
    files = _repo_files()
    missing = []
    for page in PAGES:
        for path in set(SOURCE_PATH.findall(page.read_text())):
            if "/" not in path and not path.endswith((".py", ".js")):
                continue  # a bare config or doc name is the reader's own file (my_field.toml)
            if not any(f == path or f.endswith("/" + path) for f in files):
                missing.append(f"{page.relative_to(ROOT)}: {path}")
    assert not missing, sorted(missing)


def _routes(routes):
    for route in routes:
        if isinstance(route, APIRoute):
            path = re.sub(r"\{(\w+):\w+\}", r"{\1}", route.path)  # {path:path} -> {path}
            for method in sorted(route.methods - {"HEAD"}):
                yield f"{method} {path}"
        elif isinstance(route, APIWebSocketRoute):
            yield f"WS {route.path}"
        else:  # an included router or a mount: its own routes
            yield from _routes(getattr(getattr(route, "original_router", route), "routes", []))


def test_every_route_is_in_the_api_reference():
    api = (ROOT / "docs" / "API.md").read_text()
    routes = list(_routes(create_app(Settings()).routes))
    assert "GET /api/status" in routes and "WS /ws/telemetry" in routes  # the walk works
    missing = [r for r in routes if not re.search(re.escape(r) + r"(?![\w/{])", api)]
    assert not missing, f"routes missing from docs/API.md: {missing}"
