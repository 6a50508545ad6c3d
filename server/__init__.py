"""fpv-station's server side: the FastAPI app that serves people (REST, WebSocket, video, pages)."""

from importlib import metadata

try:
    __version__ = metadata.version("fpv-station")
except metadata.PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+source"
