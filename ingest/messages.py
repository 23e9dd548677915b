"""What the ingest's stages hand each other: one type per arrow of the pipeline.

    receive ──DataIn──▶ check ──Checked──▶ store ──(ack / nack)──▶ acknowledge ──▶ receive (sends)
       │                  └──(nack)──────────────────────────────▶ acknowledge
       └──Note──────────────────────────▶ store ──Job──▶ analyse ──Analysed──▶ store ──Event──▶ publish

* `DataIn`: a data message whose header passed (`camcal.core.wire.decode_header`),
  its payload not yet checked; from the receiving thread to the checking one.
* `Checked`: a data message whose payload passed too (the image bytes, or the
  sensor rows as an array), or one part of a large sensor batch (`part`):
  the store commits a large batch a part per turn, so that one module's batch
  of 100 000 rows cannot hold up another module's frame.
* `Note`: what the store keeps of the link besides data: a link up or down, a
  module's ``hello``, ``heartbeat`` or ``command_status``.
* `Analysed`: an analysis back from the pool.

Nothing here imports a stage: each stage imports this module and the stages
below it, never one above (`lint-imports` checks the order, pyproject.toml).
"""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from camcal.core import wire
from camcal.core.clockmap import ModuleClock
from camcal.core.wire.reasons import REASONS

Key = tuple[str, str, int]  # module, boot, seq: a data message's identity forever
#: Rows of a sensor batch the store commits in one turn: a larger batch goes in parts (`Checked.part`).
PART_ROWS = 2000


@dataclass
class DataIn:
    """A data message as received: header checked, payload (``nbytes``) not yet."""

    msg: Any  # wire.FrameMsg | wire.SensorsMsg
    payload: Any  # the payload's buffer (a zmq frame's memoryview)
    received_unix_s: float
    received_mono: float
    nbytes: int
    #: The module's clock mapped onto the ship's when it arrived (`camcal.core.clockmap`).
    clock: ModuleClock = field(default_factory=ModuleClock)

    @property
    def module(self) -> str:
        return str(self.msg.module)

    @property
    def key(self) -> Key:
        return (self.msg.module, self.msg.boot, self.msg.seq)


@dataclass
class Checked(DataIn):
    """A data message whose payload passed its checks (``payload``: the image bytes of a frame, the
    rows x SENSOR_COLUMNS array of a sensor batch); or part ``part`` = (first row, rows, of rows) of a
    sensor batch that the store commits over several turns (None: all of it at once)."""

    part: tuple[int, int, int] | None = None

    @property
    def kind(self) -> str:
        return str(self.msg.type)

    @property
    def last_part(self) -> bool:
        return self.part is None or self.part[0] + self.part[1] >= self.part[2]


@dataclass
class Note:
    """Something of a module's link for the store: ``link`` (``info``: up, reason, boot, last_seq),
    ``hello``, ``heartbeat`` or ``command_status`` (``msg``)."""

    kind: str
    module: str
    msg: Any = None
    info: dict[str, Any] | None = None
    received_unix_s: float = 0.0
    received_mono: float = 0.0


@dataclass
class Analysed:
    """A frame's analysis, back from the pool (``future`` holds its result row or its failure)."""

    frame_id: int
    meta: dict[str, Any]
    future: Future[Any]


def nack(reason: str, detail: str, ref: dict[str, Any] | None = None) -> wire.Nack:
    """The refusal of a message, naming it as far as ``ref`` (type, boot, seq) could be read."""
    ref = ref or {}
    return wire.Nack(
        module="ship",
        boot=ref.get("boot"),
        seq=ref.get("seq"),
        of=ref.get("type"),
        reason=reason,
        retry=REASONS[reason].retry,
        detail=detail[:500],
    )
