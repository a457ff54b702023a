"""Atomic file replacement: readers see the old file or the complete new one, never a part."""

from __future__ import annotations

import contextlib
import os
import secrets
from pathlib import Path


@contextlib.contextmanager
def atomic_write(path):
    """Open a temporary binary file next to `path`; move it onto `path` when the block succeeds.

    Parameters
    ----------
    path : str or os.PathLike   final file; missing parent directories are created

    Yields
    ------
    file : binary file object open for writing

    Notes
    -----
    The temporary file lives in the same directory (so `os.replace` is an atomic rename on the
    same file system) and has a hidden name (a leading dot), so `list_frames` never sees it.
    It is created with mode 0o666 minus the umask, like `open(path, "wb")` would.
    On any error it is removed and `path` is left untouched. No fsync: the rename is atomic
    but not guaranteed durable across a power cut.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = create_temporary(path)
    try:
        with os.fdopen(handle, "wb") as file:
            yield file
        os.replace(temp_name, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(temp_name)
        raise


def create_temporary(path):
    """Create a new, empty, hidden file next to `path`; return (file descriptor, name)."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    while True:
        name = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
        try:
            return os.open(name, flags, 0o666), name
        except FileExistsError:
            continue
        except OSError as exc:  # name the file asked for, not the hidden temporary one
            raise type(exc)(f"cannot write {path}: {exc.strerror or exc}") from None
