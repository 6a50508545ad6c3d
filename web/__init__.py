"""What the browser runs: static pages, scripts and styles, served by the Pi (no CDN)."""

from pathlib import Path

WEB_DIR = Path(__file__).resolve().parent
