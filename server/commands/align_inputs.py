"""The inputs of an alignment (`morphspace align`, `eval-align` and the align job): the sequences
named on the command line or by a job, their frames read and converted to metres with +Y up, and
the root given as "SEQUENCE:FRAME" or a global frame index."""

from __future__ import annotations

import contextlib
from pathlib import Path, PurePosixPath

import numpy as np

from engine.mesh_io import MESH_EXTENSIONS, read_frames
from engine.mesh_io.dataset import read_capture_manifest
from engine.mesh_io.errors import MeshFormatError, MeshSequenceError
from engine.mesh_io.frames import left_out_frames, list_frames
from engine.mesh_io.natural_sort import stem_runs
from engine.surface import model_size
from server.commands.checks import read_meta
from server.units import declared_convention, meshes_to_metres, say_conventions

MAX_FRAME_SCALE = 10.0  # a frame this many times larger or smaller than its sequence's median is in other units


def resolve_inputs(inputs, only=None):
    """Sequences to align from the command-line DIRs.

    Returns
    -------
    sequences : list of dict   name, frames (path of the frame directory or zip), meta (dict or None),
                               declared (metadata that may say units and up: meta.json, the
                               dataset manifest's ``body``)
    """
    sequences = []
    for path in inputs:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such file or directory")
        if (path / "manifest.json").is_file() and (path / "sequences").is_dir():
            manifest = read_capture_manifest(path)
            names = [s["name"] for s in manifest.get("sequences", [])] or sorted(
                p.name for p in (path / "sequences").iterdir() if p.is_dir())
            if only:
                unknown = sorted(set(only) - set(names))
                if unknown:
                    raise ValueError(f"{path}: no sequence(s) {', '.join(unknown)}; it has {', '.join(names)}")
                names = [n for n in names if n in only]
            for name in names:
                sequences.append(_sequence_entry(path / "sequences" / name, manifest.get("body")))
        else:
            if only:
                raise ValueError("--only selects sequences of a capture dataset; "
                                 f"{path} is not one (no manifest.json and sequences/)")
            sequences.append(_sequence_entry(path))
    names = [s["name"] for s in sequences]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"two inputs have the same sequence name {duplicates[0]!r}; rename one directory")
    return sequences


def _sequence_entry(path, body=None):
    meta = read_meta(path) if (path / "meta.json").is_file() else None
    # a sequence's re-meshed frames; without them its consistent ones (an upload, or an aligned
    # output aligned again: "no mesh files among the 2 entries" named the wrong problem)
    frames = next((path / sub for sub in ("unstructured", "consistent") if (path / sub).is_dir()), path)
    name = (meta or {}).get("name") or (path.stem if path.suffix.lower() == ".zip" else path.name)
    if body is None and (path.parent.parent / "manifest.json").is_file():  # a sequence of a dataset
        try:
            body = read_capture_manifest(path.parent.parent).get("body")
        except (OSError, ValueError):
            body = None
    return {"name": str(name), "frames": frames, "meta": meta, "declared": [meta, body]}


def parse_root(text, sequences, lengths, label="--root"):
    """Global frame index from "SEQUENCE:FRAME" or an integer (``label`` names it in errors).
    With ``lengths`` None (the frames not counted yet) only the form, the sequence and a frame
    number from 0 are checked, and None is returned."""
    if text is None:
        return None
    if ":" in text:
        name, _, frame = text.rpartition(":")
        names = [s["name"] for s in sequences]
        if name not in names:
            only = "--only" if label.startswith("--") else "only"
            raise ValueError(f"{label} {text}: no sequence {name!r}; sequences are {', '.join(names) or 'none'}"
                             f" (those aligned: {only} picks them)")
        k = names.index(name)
        try:
            frame = int(frame)
        except ValueError:
            raise ValueError(f"{label} {text}: frame must be an integer") from None
        if lengths is None:
            if frame < 0:
                raise ValueError(f"{label} {text}: frame must be an integer from 0")
            return None
        if not 0 <= frame < lengths[k]:
            raise ValueError(f"{label} {text}: sequence {name} has frames 0..{lengths[k] - 1}")
        return int(np.sum(lengths[:k]) + frame)
    try:
        index = int(text)
    except ValueError:
        raise ValueError(f"{label} {text}: expected SEQUENCE:FRAME or a frame index") from None
    if lengths is None:
        if index < 0:
            raise ValueError(f"{label} {text}: a frame index is an integer from 0")
        return None
    total = int(np.sum(lengths))
    if not 0 <= index < total:
        raise ValueError(f"{label} {text}: there are {total} frames (0..{total - 1})")
    return index


def check_root_early(text, sequences, label="--root"):
    """:func:`parse_root` against the frame files listed, before any frame is read (a root past a
    sequence's end was refused only after reading every frame). Where a listing fails or finds no
    frames, the reading names the problem; the root is parsed again against the frames read."""
    if text is None:
        return
    with contextlib.suppress(MeshFormatError, MeshSequenceError, OSError):
        counts = np.array([len(list_frames(s["frames"])) for s in sequences], dtype=np.int64)
        if len(counts) and counts.min() > 0:
            parse_root(text, sequences, counts, label=label)


DEFAULT_FPS = 30.0  # the frame rate of inputs without a meta.json, unless --fps says


def read_inputs(sequences, progress=None, *, say=None):
    """All frames of all sequences (concatenated) and the frame count of each sequence.

    ``say(line)`` is told of files beside a sequence's frames in a mesh format that is not read
    (an ``.stl`` among ``.obj`` frames): they are left out, and the frames renumbered without them;
    and of frame files of more than one name (``frame_10.ply`` beside ``take_0004.ply``): they are
    taken in natural order all the same (`mixed_names_text`).
    """
    meshes, lengths = [], []
    total = None
    if progress is not None:  # the bar's total: every sequence's frame files, listed first
        with contextlib.suppress(MeshFormatError, MeshSequenceError):  # read_frames below names the problem
            total = sum(len(list_frames(s["frames"])) for s in sequences)
    for s in sequences:
        frames = read_frames(s["frames"], progress=(lambda d, t: progress("read", len(meshes) + d, total))
                             if progress else None)
        left_out = left_out_frames(s["frames"])
        if left_out and say is not None:
            shown = ", ".join(left_out[:5]) + (f" and {len(left_out) - 5} more" if len(left_out) > 5 else "")
            say(f"warning: {s['name']}: {len(left_out)} file(s) in a mesh format that is not read "
                f"({', '.join(MESH_EXTENSIONS)} are), left out of the sequence: {shown}")
        mixed = mixed_names_text([file_name(m.source) for m in frames])
        if mixed and say is not None:
            say(f"warning: {s['name']}: {mixed}")
        if len(frames) < 1:
            raise MeshFormatError(f"{s['frames']}: no frames")
        meshes.extend(frames)
        lengths.append(len(frames))
    return meshes, np.array(lengths, dtype=np.int64)


def mixed_names_text(names, shown=6):
    """None when every frame file of a sequence (``names``, in natural order) has one name apart from
    its number, else a line naming the names and the order the frames are taken in (``shown`` runs)::

        the frame files mix names 'frame_' and 'take_', taken in natural order: frame_1.ply to
        frame_10.ply as frames 0-9, then take_0004.ply to take_0007.ply as frames 10-13
    """
    runs = stem_runs(names)
    stems = list(dict.fromkeys(stem.casefold() for stem, _, _ in runs))
    if len(stems) < 2:
        return None
    spelled = [next(repr(stem) for stem, _, _ in runs if stem.casefold() == folded) for folded in stems]
    listed = (f"names {', '.join(spelled[:-1])} and {spelled[-1]}" if len(spelled) <= 4 else
              f"{len(spelled)} names ({spelled[0]}, {spelled[1]}, ..., {spelled[-1]})")
    if len(runs) == len(names) and len(spelled) == len(names):  # no two files share a name: nothing is numbered
        order = [f"{name} as frame {k}" for k, name in enumerate(names)]
        order = order if len(order) <= 3 else order[:2] + ["...", order[-1]]
        return f"the frame files have {len(names)} different names, taken in natural order: " + ", ".join(order)
    parts = [f"{names[first]} as frame {first}" if first == last
             else f"{names[first]} to {names[last]} as frames {first}-{last}" for _, first, last in runs[:shown]]
    more = f", ... ({len(runs)} runs in all)" if len(runs) > shown else ""
    return f"the frame files mix {listed}, taken in natural order: " + ", then ".join(parts) + more


def convert_inputs(meshes, sequences, lengths, units="auto", up="auto", *, say=None):
    """Every sequence's frames in metres with +Y up (see ``server.units``).

    Each sequence is decided on its own frames (a dataset may mix units and axes), its
    meta.json, then its dataset manifest's ``body``, consulted when the geometry cannot tell;
    ``say(line)`` is told what was decided and any doubt about it.

    Returns
    -------
    meshes : list of Mesh                      all frames, converted
    conventions : list of engine.mesh_io.Convention   one per sequence
    """
    converted, conventions, start = [], [], 0
    for s, n in zip(sequences, lengths):
        check_one_scale(meshes[start:start + n], s["name"])
        part, convention = meshes_to_metres(meshes[start:start + n], units, up,
                                            declared=declared_convention(s.get("declared", ())))
        converted.extend(part)
        conventions.append(convention)
        start += n
    if say is not None:
        say_conventions(conventions, [s["name"] for s in sequences], say)
    return converted, conventions


def check_one_scale(meshes, name):
    """A ValueError naming the first frame of sequence ``name`` whose size (of the vertices its faces
    use: stray points do not count) is more than ``MAX_FRAME_SCALE`` times larger or smaller than
    the median frame's. One sequence is in one unit: a frame saved in millimetres among frames in
    metres would otherwise be aligned as a body a thousand times too big, and every frame aligned
    from it would follow."""
    sizes = np.array([model_size(m.vertices[np.unique(m.faces)]) for m in meshes])
    median = float(np.median(sizes))
    if not median > 0:  # most frames of no extent: no scale to hold the others to
        return
    ratio = np.maximum(sizes / median, median / np.maximum(sizes, 1e-300))
    off = np.flatnonzero(ratio > MAX_FRAME_SCALE)
    if len(off):
        k = int(off[0])
        what = f"{ratio[k]:,.0f} times the size of" if sizes[k] > median else f"1/{ratio[k]:,.0f} the size of"
        more = f" ({len(off)} such frames)" if len(off) > 1 else ""
        source = getattr(meshes[k], "source", None)
        frame = f"{file_name(source)} (frame {k})" if source else f"frame {k}"
        raise ValueError(f"sequence {name!r}: {frame} is {what} the sequence's "
                         f"median frame{more}: one sequence's frames must be in the same units (convert the "
                         "frame, e.g. from millimetres to metres)")


def file_name(source):
    """The file a frame came from, from its ``Mesh.source``: a file's name in a directory, or a zip
    member's whole path (``take1/frame_0003.obj``: one zip may hold several folders' frames)."""
    archive, sep, member = str(source).rpartition(".zip:")
    return str(PurePosixPath(member)) if sep else Path(str(source)).name


def frame_label(index, sequences, lengths):
    """"SEQUENCE:FRAME" of a global frame ``index`` (the form ``--root`` takes)."""
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    k = int(np.searchsorted(starts, int(index), side="right") - 1)
    return f"{sequences[k]['name']}:{int(index) - int(starts[k])}"


__all__ = ["DEFAULT_FPS", "check_root_early", "convert_inputs", "file_name", "frame_label", "mixed_names_text",
           "parse_root", "read_inputs", "resolve_inputs"]
