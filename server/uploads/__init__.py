"""Capture datasets on the server: safe uploads, the on-disk layout, descriptions.

An upload (a zip body, or multipart/form-data whose parts are files named by their relative
path) becomes ``data_dir/datasets/<name>/`` in the capture-dataset layout that ``morphspace
build --source`` and ``morphspace align`` read (engine/mesh_io/dataset.py)::

    <name>/manifest.json                          format, sequences (written here)
    <name>/template/<mesh>                        optional rest mesh(es), e.g. template/body.obj
    <name>/sequences/<seq>/meta.json              name, fps, cyclic, frames, topology, ...
    <name>/sequences/<seq>/consistent/<frames>    frames sharing one mesh structure, or
    <name>/sequences/<seq>/unstructured/<frames>  frames with a mesh each (align them first)

Accepted upload layouts (one folder wrapping everything is stripped): ``<seq>/<frame>`` (a folder
per sequence), ``<seq>/{consistent,unstructured}/<frame>``, the capture-dataset layout above,
or frames at the top level (one sequence named like the dataset). ``<seq>/meta.json`` may give
``fps`` and ``cyclic`` (defaults from the request). Hidden files and ``__MACOSX/`` are skipped;
any other file type, a path that is absolute or has ``..``, a symlink, a name with unusual
characters, too many files or bytes, or a compression ratio typical of a zip bomb is refused
with a 4xx naming the file. Every frame is read with engine.mesh_io before the dataset becomes
visible: the upload is assembled in ``datasets/.upload-<id>/`` and renamed into place, so a
failed or partial upload never shows.

Nothing here imports FastAPI: errors are ``UploadError(status, message)``.

One concept per module: ``rules.py`` (names, limits, UploadError), ``extract.py`` (zip and
multipart bodies to checked files), ``assemble.py`` (files to a validated dataset layout),
``store.py`` (datasets on disk: publish, remove, list, describe, pictures), ``receive.py``
(the whole upload).
"""

from engine.names import NAME
from server.uploads.assemble import FrameStats, assemble_dataset, sequence_meta
from server.uploads.receive import receive_dataset
from server.uploads.rules import KINDS, Limits, UploadError, check_name, dataset_path
from server.uploads.store import (
    PICTURES,
    clean_stale,
    dataset_names,
    describe_dataset,
    picture_path,
    publish_dir,
    remove_dir,
    sequence_names,
)

__all__ = ["KINDS", "NAME", "PICTURES", "FrameStats", "Limits", "UploadError", "assemble_dataset", "check_name",
           "clean_stale", "dataset_names", "dataset_path", "describe_dataset", "picture_path", "publish_dir",
           "receive_dataset", "remove_dir", "sequence_meta", "sequence_names"]
