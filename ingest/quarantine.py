"""Messages the ingest failed to store twice while others were stored: kept aside, never retried.

A message that makes the store thread fail could otherwise come back after
every ``welcome`` and fail again, for ever. The second time it fails while
other messages were stored meanwhile (so the fault is the message's, not a
full disk's), its header and payload go to ``<data>/quarantine/`` for
someone to inspect, and every later copy of it is refused at once as
``quarantined``. The module keeps its own copy on the SD card.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("camcal.ingest")

Key = tuple[str, str, int, str]  # module, boot, seq, sha256 of the payload


class Quarantine:
    """The quarantine folder of a data folder, and the keys it holds."""

    def __init__(self, root: Path) -> None:
        self.root = root / "quarantine"
        self._keys: set[Key] = set()
        for meta in self.root.glob("*.json") if self.root.is_dir() else ():
            try:
                h = json.loads(meta.read_text())["header"]
                self._keys.add((h["module"], h["boot"], int(h["seq"]), h["sha256"]))
            except (OSError, ValueError, KeyError, TypeError):
                continue

    def holds(self, key: Key) -> bool:
        return key in self._keys

    def put(self, key: Key, header: dict[str, Any], payload: bytes, error: str) -> Path | None:
        """Keep a message (header as JSON, payload as bytes); returns the JSON file's path."""
        self._keys.add(key)
        module, boot, seq, sha = key
        stem = f"{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}-{module}-{boot}-{seq}-{sha[:12]}"
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            (self.root / f"{stem}.bin").write_bytes(payload)
            meta = self.root / f"{stem}.json"
            meta.write_text(
                json.dumps({"header": header, "error": error, "t_unix_s": time.time()}, default=str)
            )
            return meta
        except OSError as exc:  # the key is still held: no crash loop, even if the disk refuses
            log.error("could not keep quarantined message %s/%s/%d: %s", module, boot, seq, exc)
            return None
