"""The control token of a station started with no token set: made once, kept in a file
only its user can read, and shown in the URL printed at start (as Jupyter does), so that
`make run` is secure from the first start and the pilot still just opens one link."""

from __future__ import annotations

import os
import secrets
from pathlib import Path


def default_token_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "fpv-station" / "token"


def load_or_create_token(path: Path | None = None) -> str:
    """The token in `path` (default: default_token_file()), made and stored if absent."""
    path = path or default_token_file()
    try:
        token = path.read_text().strip()
        if token:
            return token
    except FileNotFoundError:
        pass
    token = secrets.token_urlsafe(24)
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token
