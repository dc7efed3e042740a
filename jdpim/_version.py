"""The installed version of jdpim (``0.0.0`` when run from a source tree without installation)."""

import importlib.metadata as _metadata

try:
    __version__ = _metadata.version("jdpim")
except _metadata.PackageNotFoundError:
    __version__ = "0.0.0"
