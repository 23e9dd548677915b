"""The browser dashboard: static pages served by the server (no CDN, no web fonts)."""

from pathlib import Path

STATIC_DIR = Path(__file__).with_name("static")
