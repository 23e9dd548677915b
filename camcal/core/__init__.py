"""The ground both sides stand on: what the module, the ship and the command line share.

Nothing here imports anything of ours above it (``analysis``, ``lrm``,
``ingest``, ``storage``, ``server``, the command line); the layers contract
in ``pyproject.toml`` checks it. What lives here:

* `camcal.core.wire` — the module ↔ ship protocol (one home for the format);
* `camcal.core.frameset` — the on-disk frame set (setup, manifest, writer);
* `camcal.core.images` — frame images: decode (PNG/TIFF) and encode;
* `camcal.core.files` — writes that survive a power cut (`write_atomic`, `fsync_dir`);
* `camcal.core.schedule` — exposure schedules;
* `camcal.core.settings` — typed settings from the environment and a config file;
* `camcal.core.calibrations` — lab calibrations a frame set refers to;
* `camcal.core.parallel` — the one worker pool (a fork server with the heavy modules loaded), and
  threads for the work that runs outside the interpreter's lock (a frame set's decoding and analysis);
* `camcal.core.supervise`, `camcal.core.procinfo` — how a camcal process starts, reports and ends;
* `camcal.core.logs` — structured logging.
"""

__version__ = "0.1.0"
