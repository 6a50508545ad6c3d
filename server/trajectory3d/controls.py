"""The GUI in the viser panel: follow the vehicle or fly a free camera, clear the trail,
pick the colour-coding, show or hide the field. Every one of them changes what all
viewers see, so the relay passes their changes only from a viewer with the control token
(`inputs()`, server/trajectory3d/gate.py).

viser runs GUI callbacks on its own worker threads. They never touch the scene's trail
state; they record a request that the update loop applies on its next tick (at most one
update period later), so the scene has one writer.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import viser

from fpv_station.server.trajectory3d.colors import COLOR_BY_CHOICES, ColorBy
from fpv_station.server.trajectory3d.gate import ViewerInput, gui_uuid


@dataclass(slots=True)
class Requests:
    """What the GUI asked for since the last tick."""

    clear: bool = False
    color_by: ColorBy | None = None
    field_visible: bool | None = None

    @property
    def any(self) -> bool:
        return self.clear or self.color_by is not None or self.field_visible is not None


class Controls:
    def __init__(self, server: viser.ViserServer, color_by: ColorBy, follow: bool = False) -> None:
        self._lock = threading.Lock()
        self._requests = Requests()
        gui = server.gui
        # A viewer without the token sees them too (viser's GUI is one for all): say so.
        shared = "; for every viewer, from the pilot's page (control token)"
        with gui.add_folder("Trajectory"):
            self.follow = gui.add_checkbox(
                "Follow vehicle",
                initial_value=follow,
                hint="Keep the cameras on the vehicle; off = free camera" + shared,
            )
            self.color_by = gui.add_dropdown(
                "Colour by",
                options=COLOR_BY_CHOICES,
                initial_value=color_by,
                hint="Colour the trail by height or speed" + shared,
            )
            self.show_field = gui.add_checkbox(
                "Show field", initial_value=True, hint="Show the flying field" + shared
            )
            self.clear = gui.add_button("Clear trail", hint="Drop the trail so far" + shared)
            self.status = gui.add_markdown("waiting for a position fix")

        @self.clear.on_click
        def _(_: viser.GuiEvent) -> None:
            with self._lock:
                self._requests.clear = True

        @self.color_by.on_update
        def _(_: viser.GuiEvent) -> None:
            if self.color_by.value not in COLOR_BY_CHOICES:
                return
            with self._lock:
                self._requests.color_by = self.color_by.value  # type: ignore[assignment]

        @self.show_field.on_update
        def _(_: viser.GuiEvent) -> None:
            with self._lock:
                self._requests.field_visible = bool(self.show_field.value)

    def inputs(self) -> dict[str, ViewerInput]:
        """The inputs, by uuid, and their values: all shared (they need the token)."""
        return {
            gui_uuid(self.follow): ViewerInput(bool),
            gui_uuid(self.color_by): ViewerInput(str, choices=tuple(COLOR_BY_CHOICES)),
            gui_uuid(self.show_field): ViewerInput(bool),
            gui_uuid(self.clear): ViewerInput(bool),
        }

    def take_requests(self) -> Requests:
        """The pending requests, reset to none."""
        with self._lock:
            out, self._requests = self._requests, Requests()
        return out

    def set_status(self, text: str) -> None:
        if self.status.content != text:  # skip the message when nothing changed
            self.status.content = text
