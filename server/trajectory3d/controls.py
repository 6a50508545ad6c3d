"""The GUI in the live viser panel: follow the vehicle or fly a free camera, clear the
trail, pick the colour-coding, show or hide the field. Every one of them changes what all
viewers see, so only a viewer that presented the control token gets them: viser builds
them for that client alone (its per-client GUI) when the relay marks its connection as
the pilot's (`PilotPath`, server/trajectory3d/gate.py). An anonymous viewer watches: it
sees the scene and the status line, and no control it could not use. The relay passes
GUI changes only from a marked viewer too, and viser routes a client's change to that
client's own inputs only.

The settings are the panel's, one for all the pilots' GUIs: a change from one pilot is
shown in the others'. viser runs GUI callbacks on its own worker threads; they record a
request that the update loop applies on viser's loop on its next tick (at most one update
period later), so the scene and the GUIs have one writer.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import viser

from fpv_station.server.trajectory3d.colors import COLOR_BY_CHOICES, ColorBy
from fpv_station.server.trajectory3d.gate import ViewerInput, gui_uuid


@dataclass(slots=True)
class Requests:
    """What the pilots asked for since the last tick."""

    clear: bool = False
    color_by: ColorBy | None = None
    field_visible: bool | None = None
    follow: bool | None = None

    @property
    def any(self) -> bool:
        return (
            self.clear
            or self.color_by is not None
            or self.field_visible is not None
            or self.follow is not None
        )


@dataclass(frozen=True, slots=True)
class PilotGui:
    """One pilot's inputs in the panel."""

    follow: viser.GuiCheckboxHandle
    color_by: viser.GuiDropdownHandle
    show_field: viser.GuiCheckboxHandle
    clear: viser.GuiButtonHandle

    def inputs(self) -> dict[str, ViewerInput]:
        return {
            gui_uuid(self.follow): ViewerInput(bool),
            gui_uuid(self.color_by): ViewerInput(str, choices=tuple(COLOR_BY_CHOICES)),
            gui_uuid(self.show_field): ViewerInput(bool),
            gui_uuid(self.clear): ViewerInput(bool),
        }


class Controls:
    def __init__(self, server: viser.ViserServer, color_by: ColorBy, follow: bool = False) -> None:
        self._lock = threading.Lock()
        self._requests = Requests()
        # The panel's settings, as the update loop last applied them.
        self.follow = follow
        self.color_by: ColorBy = color_by
        self.show_field = True
        self.pilots: dict[int, PilotGui] = {}  # by viser client id
        # The pilots' inputs by uuid: changed on viser's loop as pilots come and go, read
        # by the relays on the station's loop (one key at a time: atomic in CPython).
        self._inputs: dict[str, ViewerInput] = {}
        self.status = server.gui.add_markdown("waiting for a position fix")  # for everyone

    def add_pilot(self, client: viser.ClientHandle) -> PilotGui:
        """Build a pilot's controls in its own GUI (on viser's loop: its connect
        callback), showing the panel's current settings."""
        gui = client.gui
        shared = "; for every viewer"
        with gui.add_folder("Trajectory", order=0):
            pilot = PilotGui(
                follow=gui.add_checkbox(
                    "Follow vehicle",
                    initial_value=self.follow,
                    hint="Keep the cameras on the vehicle; off = free camera" + shared,
                ),
                color_by=gui.add_dropdown(
                    "Colour by",
                    options=COLOR_BY_CHOICES,
                    initial_value=self.color_by,
                    hint="Colour the trail by height or speed" + shared,
                ),
                show_field=gui.add_checkbox(
                    "Show field",
                    initial_value=self.show_field,
                    hint="Show the flying field" + shared,
                ),
                clear=gui.add_button("Clear trail", hint="Drop the trail so far" + shared),
            )

        # A pilot's own change comes with its client; the update loop's echo into the
        # other pilots' inputs (`show`) comes without one and asks for nothing.
        @pilot.clear.on_click
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                with self._lock:
                    self._requests.clear = True

        @pilot.color_by.on_update
        def _(event: viser.GuiEvent) -> None:
            value = pilot.color_by.value
            if event.client is not None and value in COLOR_BY_CHOICES:
                with self._lock:
                    self._requests.color_by = value

        @pilot.show_field.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                with self._lock:
                    self._requests.field_visible = bool(pilot.show_field.value)

        @pilot.follow.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is not None:
                with self._lock:
                    self._requests.follow = bool(pilot.follow.value)

        self.pilots[client.client_id] = pilot
        self._inputs.update(pilot.inputs())
        return pilot

    def remove_pilot(self, client: viser.ClientHandle) -> None:
        """A pilot left (viser's disconnect callback): its inputs are gone with it."""
        pilot = self.pilots.pop(client.client_id, None)
        if pilot is not None:
            for uuid in pilot.inputs():
                self._inputs.pop(uuid, None)

    def inputs(self) -> Mapping[str, ViewerInput]:
        """The pilots' inputs by uuid (all shared: they need the token), as a live view:
        a relay's rules see the inputs of a pilot whose GUI was built after it opened."""
        return MappingProxyType(self._inputs)

    def take_requests(self) -> Requests:
        """The pending requests, reset to none; the settings they change are recorded and
        shown in every pilot's inputs (on viser's loop: the update loop's tick)."""
        with self._lock:
            out, self._requests = self._requests, Requests()
        if out.color_by is not None:
            self.color_by = out.color_by
        if out.field_visible is not None:
            self.show_field = out.field_visible
        if out.follow is not None:
            self.follow = out.follow
        if out.any:
            self.show()
        return out

    def show(self) -> None:
        """Every pilot's inputs to the panel's settings (a no-op where they agree)."""
        # viser defines a method between `value`'s getter and setter, which hides the
        # setter from mypy: the stores below are viser's documented API.
        for pilot in list(self.pilots.values()):
            pilot.follow.value = self.follow  # type: ignore[misc]
            pilot.color_by.value = self.color_by  # type: ignore[misc]
            pilot.show_field.value = self.show_field  # type: ignore[misc]

    def set_status(self, text: str) -> None:
        if self.status.content != text:  # skip the message when nothing changed
            self.status.content = text
