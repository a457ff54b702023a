"""Arrays a blender derives from a motion space, kept in files so that processes share them.

Blenders re-lay out some of a space's arrays for their hot path: the non-linear blender keeps
the per-tet rotations, stretches and surface detail in component-major order (about 60 MB of a
64 MB, 3,000-vertex space), the hybrid blender flat correction indices and dense correction rows
(about 15 MB there). Built in each process, those are each process's own memory, once per
server worker. ``DerivedStore(directory)`` keeps them instead in `.mspace` containers of their
own, one per (space file, blender), mapped read-only like the space: every process that maps
one shares its pages.

A derived file is named ``<space stem>.<16 hex digits>.<kind>.mspace``, the hex digits from the
space file's header checksum (which covers every array's checksum), and records that checksum
and the build parameters in its metadata: a rebuilt space, other parameters or a damaged file
give a new file, built once (concurrent builders wait on a lock file, the first one writes), and
the files of older versions of the same space and kind are removed. Deleting the directory is
always safe: the files are built again when next needed.
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

from engine.motion_space.container import Container, MotionSpaceError, write_container

FORMAT = "morphspace-derived-arrays"


class DerivedStore:
    """Derived arrays of motion spaces, in ``directory`` (created when first written)."""

    def __init__(self, directory):
        self.directory = Path(directory)

    def path(self, container, kind):
        return self.directory / f"{container.path.stem}.{container.checksum[:16]}.{kind}.mspace"

    def load(self, container, kind, parameters, build):
        """The arrays ``build()`` returns for ``container`` (an open space file), mapped from
        the derived file of ``kind`` (a word naming the blender) made with ``parameters`` (JSON
        data the result depends on); built and written first if there is no such file yet.

        Returns a Container (``container[name]`` is a read-only mapped array).
        """
        path = self.path(container, kind)
        metadata = {"format": FORMAT, "kind": kind, "source": container.path.name,
                    "source_checksum": container.checksum, "parameters": parameters}
        found = _open_matching(path, metadata)
        if found is not None:
            return found
        self.directory.mkdir(parents=True, exist_ok=True)
        with _locked(self.directory / f".{container.path.stem}.{kind}.lock"):
            found = _open_matching(path, metadata)  # another process built it meanwhile
            if found is None:
                write_container(path, build(), metadata)
                found = Container.open(path)
            version = re.compile(re.escape(container.path.stem) + r"\.[0-9a-f]{16}\." + re.escape(kind) + r"\.mspace")
            for old in self.directory.glob(f"{container.path.stem}.*.{kind}.mspace"):
                if old != path and version.fullmatch(old.name):
                    with contextlib.suppress(FileNotFoundError):
                        old.unlink()  # an older version's; processes mapping it keep their mapping
        return found


def _open_matching(path, metadata):
    """The derived file at ``path`` if it is intact and made from what ``metadata`` says, else None."""
    try:
        found = Container.open(path)
    except (MotionSpaceError, OSError):
        return None
    if found.metadata != metadata:
        found.close()
        return None
    return found


@contextlib.contextmanager
def _locked(path):
    import fcntl  # POSIX; imported here so that reading spaces works everywhere

    handle = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)
