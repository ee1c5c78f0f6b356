"""Self-written example ESI files and topologies: the embedded default of ``ecatcfg demo``."""

from importlib.resources import files
from pathlib import Path


def example_dir() -> Path:
    """The folder holding the example files (inside the installed package)."""
    return Path(str(files(__name__)))
