"""What an upload and a dataset name may be: names, limits, and ``UploadError``, the refusal.

Nothing in server/uploads/ imports FastAPI: a refused upload or dataset request raises
``UploadError(status, message)`` and the routes (server/api/datasets.py) answer with it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from engine.names import is_name

PART = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.@+=,() -]{0,127}$")
KINDS = ("consistent", "unstructured")
MAX_DEPTH = 5
ZIP_MAX_RATIO = 100  # uncompressed / compressed, for members over ZIP_RATIO_FLOOR bytes
ZIP_RATIO_FLOOR = 1 << 20
META_MAX_BYTES = 64 * 1024
CHUNK = 1 << 20
STAGING_PREFIX = ".upload-"
TRASH_PREFIX = ".trash-"


class UploadError(Exception):
    """A refused upload or dataset request: HTTP ``status`` and a message naming the problem."""

    def __init__(self, status, message):
        super().__init__(message)
        self.status, self.message = status, message


@dataclass
class Limits:
    max_bytes: int
    max_files: int
    max_unpacked: int

    @classmethod
    def from_settings(cls, settings):
        return cls(settings.max_upload_bytes, settings.max_upload_files, settings.max_unpacked_bytes)


def check_name(name, what="dataset"):
    if not is_name(name):
        raise UploadError(422, f"{name!r} is not a valid {what} name: use letters, digits, '_', '-', '.' "
                               "(at most 128, not starting with '.', no '..')")
    return name


def dataset_path(settings, name):
    return settings.datasets_dir / check_name(name)
