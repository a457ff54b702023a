"""Where a sequence's frames live: a directory of mesh files or a zip archive of them.

`list_frames` lists the frame names in natural order; `FrameContainer` reads them one at a
time. Zip members are read into memory, never extracted, so a member name such as
``../../etc/passwd`` is only ever a label (no zip-slip); each member's uncompressed size and
the total are capped (zip-bomb guard).
"""

from __future__ import annotations

import os
import posixpath
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from .errors import MeshFormatError, MeshSequenceError
from .mesh_file import MESH_EXTENSIONS, mesh_file_type, read_mesh
from .natural_sort import natural_key

DEFAULT_MAX_MEMBER_BYTES = 512 * 2**20  # 512 MiB per zip member, uncompressed
DEFAULT_MAX_TOTAL_BYTES = 8 * 2**30  # 8 GiB for all mesh members of one zip, uncompressed


def list_frames(
    path, *, max_member_bytes=DEFAULT_MAX_MEMBER_BYTES, max_total_bytes=DEFAULT_MAX_TOTAL_BYTES
):
    """Names of the mesh files in a directory or zip archive, in natural order.

    Parameters
    ----------
    path : str or os.PathLike
        A directory (not searched recursively) or a zip archive (members in sub-folders
        included).
    max_member_bytes : int   refuse a zip whose mesh member is larger than this uncompressed
    max_total_bytes : int    refuse a zip whose mesh members add up to more than this

    Returns
    -------
    names : list of str
        File names (directory) or member paths (zip) with extension .obj, .ply, .off or .glb
        (any case), sorted with `natural_key`. Hidden files (any path part starting with "."),
        ``__MACOSX/`` entries and other extensions are left out.

    Raises
    ------
    MeshSequenceError   not a directory or zip, or no mesh files in it
    MeshFormatError     unreadable zip, or a member or the total over its size limit
    """
    with FrameContainer(path, max_member_bytes, max_total_bytes) as frames:
        return list(frames.names)


# Mesh formats of other tools: a file in one this package does not read (``mesh_file_type`` None)
# beside the frames is most likely a frame delivered in another format, so callers say it was left out.
OTHER_MESH_EXTENSIONS = (".stl", ".fbx", ".abc", ".gltf", ".dae", ".3ds", ".wrl", ".x3d", ".vtk",
                         ".vtu", ".usd", ".usda", ".usdc", ".usdz", ".blend")


def left_out_frames(path):
    """Names of files in ``path`` (a directory or zip of frames) in a mesh format this package does
    not read (an ``.stl`` among ``.obj`` frames), sorted naturally; ``[]`` when there are none or
    ``path`` cannot be listed (reading the frames reports that)."""
    path = Path(path)
    try:
        if path.is_dir():
            names = [entry.name for entry in os.scandir(path) if entry.is_file() and not entry.name.startswith(".")]
        else:
            with zipfile.ZipFile(path) as archive:
                names = [info.filename for info in archive.infolist()
                         if not info.is_dir() and not _hidden(info.filename)]
    except (OSError, zipfile.BadZipFile):
        return []
    return sorted((name for name in names if mesh_file_type(name) is None
                   and Path(name).suffix.lower() in OTHER_MESH_EXTENSIONS), key=natural_key)


class FrameContainer:
    """Open directory or zip archive of frames; use as a context manager.

    Parameters
    ----------
    path : str or os.PathLike   directory or zip archive
    max_member_bytes, max_total_bytes : int   zip size limits, see `list_frames`

    Attributes
    ----------
    names : list of str   frame names in natural order (never empty)
    """

    def __init__(self, path, max_member_bytes, max_total_bytes):
        self.path = Path(path)
        self.max_member_bytes = int(max_member_bytes)
        self.max_total_bytes = int(max_total_bytes)
        self.archive = None
        self.members = {}
        self.bytes_read = 0
        if self.path.is_dir():
            self.names = self._list_directory()
        elif self.path.is_file():
            if mesh_file_type(self.path) is not None:
                raise MeshSequenceError(
                    f"{self.path}: is a single mesh file; a sequence is a directory or a zip "
                    f"archive of frames"
                )
            self.names = self._list_zip()
        else:
            raise MeshSequenceError(f"{self.path}: no such directory or zip archive")
        self.names.sort(key=natural_key)

    def __enter__(self):
        return self

    def __exit__(self, *exc_info):
        self.close()

    def close(self):
        if self.archive is not None:
            self.archive.close()
            self.archive = None

    def source(self, name):
        """The file a frame comes from, as used in messages: a path or ``archive.zip:member``."""
        if self.archive is None:
            return str(self.path / name)
        return f"{self.path}:{name}"

    def read(self, name):
        """Read and validate one frame.

        Parameters
        ----------
        name : str   one of `names`

        Returns
        -------
        mesh : Mesh   with `source` set to `source(name)`
        """
        if self.archive is None:
            return read_mesh(self.path / name, name=self.source(name))
        return read_mesh(self._read_member(name), name=self.source(name), resources=self._member_resources(name))

    def _member_resources(self, name):
        """Resource reader for a zip member: the files it refers to, relative to its folder."""
        folder = posixpath.dirname(name)

        def read(reference):
            member = posixpath.normpath(posixpath.join(folder, reference))
            try:
                info = self.archive.getinfo(member)
            except KeyError:
                raise MeshFormatError(f"{self.source(name)}: refers to {reference!r}, which is not in the "
                                      f"archive (looked for member {member!r})") from None
            return self._read_info(info, f"{self.path}:{member}")
        return read

    def _list_directory(self):
        try:
            entries = list(os.scandir(self.path))
        except OSError as err:
            raise MeshSequenceError(
                f"{self.path}: cannot list the directory ({err.strerror})"
            ) from err
        if not entries:
            raise MeshSequenceError(f"{self.path}: the directory is empty")
        names = [
            entry.name
            for entry in entries
            if not entry.name.startswith(".")
            and mesh_file_type(entry.name) is not None
            and entry.is_file()
        ]
        if not names:
            raise MeshSequenceError(
                f"{self.path}: no mesh files ({', '.join(MESH_EXTENSIONS)}) among the "
                f"{len(entries)} entries of the directory"
            )
        return names

    def _list_zip(self):
        try:
            self.archive = zipfile.ZipFile(self.path)
        except (zipfile.BadZipFile, OSError) as err:
            raise MeshFormatError(
                f"{self.path}: not a directory, and not a readable zip archive ({err})"
            ) from err
        infos = self.archive.infolist()
        for info in infos:
            if info.is_dir() or _hidden(info.filename) or mesh_file_type(info.filename) is None:
                continue
            if info.filename in self.members:
                raise MeshFormatError(f"{self.path}: member {info.filename!r} appears twice")
            self.members[info.filename] = info
        if not self.members:
            self.close()
            raise MeshSequenceError(
                f"{self.path}: no mesh files ({', '.join(MESH_EXTENSIONS)}) among the "
                f"{len(infos)} members of the zip archive"
            )
        for name, info in self.members.items():
            if info.file_size > self.max_member_bytes:
                self.close()
                raise MeshFormatError(
                    f"{self.path}:{name}: uncompressed size {info.file_size} bytes exceeds the "
                    f"limit of {self.max_member_bytes} bytes (max_member_bytes)"
                )
        total = sum(info.file_size for info in self.members.values())
        if total > self.max_total_bytes:
            self.close()
            raise MeshFormatError(
                f"{self.path}: the mesh members add up to {total} bytes uncompressed, over the "
                f"limit of {self.max_total_bytes} bytes (max_total_bytes)"
            )
        return list(self.members)

    def _read_member(self, name):
        return self._read_info(self.members[name], self.source(name))

    def _read_info(self, info, source):
        try:
            with self.archive.open(info) as member:
                # Read at most one byte past the limit: the declared size may be a lie.
                data = member.read(self.max_member_bytes + 1)
        except (zipfile.BadZipFile, zlib.error, EOFError, OSError, NotImplementedError) as err:
            raise MeshFormatError(f"{source}: cannot read the zip member ({err})") from err
        except RuntimeError as err:  # encrypted member
            raise MeshFormatError(f"{source}: cannot read the zip member ({err})") from err
        if len(data) > self.max_member_bytes:
            raise MeshFormatError(
                f"{source}: uncompressed size exceeds the limit of {self.max_member_bytes} "
                f"bytes (max_member_bytes)"
            )
        self.bytes_read += len(data)
        if self.bytes_read > self.max_total_bytes:
            raise MeshFormatError(
                f"{source}: the zip's members add up to more than {self.max_total_bytes} "
                f"bytes uncompressed (max_total_bytes)"
            )
        return data


def _hidden(member):
    """True for ``__MACOSX/`` entries and any member with a path part starting with a dot."""
    parts = PurePosixPath(member.replace("\\", "/")).parts
    return any(part == "__MACOSX" or part.startswith(".") for part in parts)
