"""The base of every settings section: each part declares its own section next to its
code, and `server.settings.Settings` composes them into the station's one settings object."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pydantic import AfterValidator, BaseModel, ConfigDict


class Section(BaseModel):
    """A settings section: unknown keys are errors (a typo must not pass silently), and
    assignments are validated like loading."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)


def checked_by(check: Callable[[Any], object]) -> AfterValidator:
    """A field validator (`Annotated[T | None, checked_by(load)]`) that runs `check` on a
    value that is set, so that a bad file or spec fails when the settings load; `check`
    raises a ValueError saying what is wrong."""

    def run(value: Any) -> Any:
        if value is not None:
            check(value)
        return value

    return AfterValidator(run)
