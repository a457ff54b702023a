"""Atomic file replacement: readers see the old file or the complete new one, never a part."""

from __future__ import annotations

import contextlib
import glob
import os
import secrets
from pathlib import Path

TEMPORARY_SUFFIX = ".tmp"  # of the hidden temporary file, ".{name}.{12 hex digits}.tmp"
_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)


def atomic_write(path):
    """A context manager: a temporary binary file next to `path`, moved onto `path` when the block succeeds.

    Parameters
    ----------
    path : str or os.PathLike   final file; missing parent directories are created

    Returns
    -------
    AtomicFile, whose ``with`` block gets the binary file object open for writing

    Notes
    -----
    The temporary file lives in the same directory (so `os.replace` is an atomic rename on the
    same file system) and has a hidden name (a leading dot), so `list_frames` never sees it.
    It is created with mode 0o666 minus the umask, like `open(path, "wb")` would.
    On any error it is removed and `path` is left untouched. No fsync: the rename is atomic
    but not guaranteed durable across a power cut.
    """
    return AtomicFile(path)


class AtomicFile:
    """The context manager behind `atomic_write`.

    A class rather than a generator: a signal's exception (SIGTERM is raised as one, see
    ``server.cli``) that came just after a generator had created its temporary file but before
    the ``with`` block was entered skipped the generator's clean-up until the generator was
    dropped, after the caller's own clean-up (5 exports of 60 signalled while writing frames kept
    their directory). Here the name is chosen before the file is created, so every step after
    that removes it on the way out. One window stays: a signal taken as ``__exit__`` starts, before
    its ``try`` (Python checks for signals on entering a function), a few bytecodes after the
    block's last call. A ``__del__`` could remove the file then, but a signal taken inside
    ``__del__``, which would run after every write, is printed and lost; callers that remove a
    directory they made use `discard_partial`, which finds hidden temporaries too.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.temp = None
        self.file = None

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            while self.file is None:
                self.temp = self.path.parent / f".{self.path.name}.{secrets.token_hex(6)}{TEMPORARY_SUFFIX}"
                try:
                    self.file = os.fdopen(os.open(self.temp, _FLAGS, 0o666), "wb")
                except FileExistsError:  # another writer's: not ours to remove
                    self.temp = None
                except OSError as exc:  # name the file asked for, not the hidden temporary one
                    self.temp = None
                    raise type(exc)(f"cannot write {self.path}: {exc.strerror or exc}") from None
            return self.file
        except BaseException:
            self._discard()
            raise

    def __exit__(self, kind, value, traceback):
        try:
            self.file.close()
            if kind is None:
                os.replace(self.temp, self.path)
                self.temp = None
        finally:
            self._discard()
        return False

    def _discard(self):
        if self.file is not None:
            with contextlib.suppress(OSError):
                self.file.close()
        if self.temp is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.temp)
            self.temp = None


def discard_partial(directory, names, created):
    """Clean-up after an interrupted or failed write of several files into ``directory``: remove
    ``names`` and their hidden temporaries, then ``directory`` itself if the writer ``created`` it
    and it is empty."""
    directory = Path(directory)
    for name in names:
        (directory / name).unlink(missing_ok=True)
        for temporary in directory.glob(f".{glob.escape(name)}.*{TEMPORARY_SUFFIX}"):
            temporary.unlink(missing_ok=True)
    if created:
        with contextlib.suppress(OSError):
            directory.rmdir()
