"""morphspace server: CLI, REST and WebSocket streaming on top of the engine."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("morphspace")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"
