"""The base of every settings section: each part declares its own section next to its
code, and `server.settings.Settings` composes them into the station's one settings object."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Section(BaseModel):
    """A settings section: unknown keys are errors (a typo must not pass silently), and
    assignments are validated like loading."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)
