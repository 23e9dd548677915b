"""camcal: camera-based optical calibration for deep-sea neutrino telescopes.

Layers, top to bottom (``pyproject.toml`` holds the contract ``make test`` checks):
the command line and the applications (`camcal.cli`, `camcal.pipeline`,
`camcal.fitset`, `camcal.report`, …) → ``server`` → ``ingest``, ``lrm`` →
``storage`` → ``analysis`` → `camcal.core`, the ground both sides stand on.
"""

from camcal.core import __version__

__all__ = ["__version__"]
