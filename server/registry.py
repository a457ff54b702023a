"""The motion spaces a server offers: every ``*.mspace`` file in one directory.

The directory is scanned on every listing, so a space written there (atomically, by
``morphspace build`` or a build job) appears without a restart, and a rebuilt one is reopened.
Names are file stems (``locomotion.mspace`` -> ``locomotion``); nothing outside the directory
can be named.
"""

from __future__ import annotations

import gc
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from engine.motion_space.container import MotionSpaceError
from engine.motion_space.derived import DerivedStore
from engine.motion_space.space import MotionSpace
from engine.names import NAME, is_name
from engine.player import MODES

SUFFIX = ".mspace"


def within(exc, directory):
    """``str(exc)`` with ``directory`` taken off the paths in it: a client is told the file by its
    name in the data directory, never where the server keeps it."""
    return str(exc).replace(f"{Path(directory)}/", "")


def named_path(directory, name, suffix, error, what):
    """``directory / (name + suffix)`` for a valid file-stem name, else ``error`` naming ``what``."""
    if not is_name(name):
        raise error(f"{name!r} is not a {what} name (letters, digits, '_', '-', '.'; not starting with '.', "
                    "no '..')")
    return Path(directory) / f"{name}{suffix}"


def named_files(directory, suffix):
    """Sorted stems of the files ``*suffix`` in ``directory`` whose stems are valid names."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    return sorted(p.name[:-len(suffix)] for p in directory.iterdir()
                  if p.name.endswith(suffix) and p.is_file() and NAME.match(p.name[:-len(suffix)]))


class UnknownSpace(LookupError):
    """No such motion space (or an unusable name)."""


class BrokenSpace(RuntimeError):
    """The file is there but cannot be read as a motion space."""


@dataclass(frozen=True)
class _Entry:
    stamp: tuple
    space: MotionSpace
    bounds: np.ndarray  # (2, 3) float32 quantisation box (root-local)


def quantisation_box(space, margin=0.1):
    """(2, 3) float32 box the 16-bit codec spans: the sources' bounds (root-local, every phase)
    grown by ``margin`` of the extent on each side, since non-linear blends leave the sources'
    hull a little. Vertices outside are clamped (and said so by the frame's ``clipped`` count)."""
    bounds = space.metadata.get("bounds")
    if bounds is None:
        flat = np.asarray(space.sources).reshape(-1, 3)
        bounds = [flat.min(axis=0), flat.max(axis=0)]
    lo, hi = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
    pad = margin * (hi - lo).max()
    return np.stack([lo - pad, hi + pad]).astype(np.float32)


class SpaceRegistry:
    """Opens motion spaces from ``directory`` on demand and keeps them open while unchanged.

    ``derived``: a directory for the arrays the blenders derive from each space (DerivedStore),
    mapped so that the server's worker processes share them; None: each process makes its own.
    """

    def __init__(self, directory, derived=None):
        self.directory = Path(directory)
        self.derived = DerivedStore(derived) if derived is not None else None
        self._entries = {}
        self._lock = threading.Lock()

    def path(self, name):
        return named_path(self.directory, name, SUFFIX, UnknownSpace, "motion space")

    def names(self):
        """Sorted names of the spaces in the directory now."""
        return named_files(self.directory, SUFFIX)

    def _open(self, name):
        path = self.path(name)
        try:
            st = path.stat()
        except FileNotFoundError:
            raise UnknownSpace(f"no motion space {name!r} (have: {', '.join(self.names()) or 'none'})") from None
        stamp = (st.st_ino, st.st_mtime_ns, st.st_size)
        with self._lock:
            entry = self._entries.get(name)
            if entry is not None and entry.stamp == stamp:
                return entry
        try:
            space = MotionSpace.open(path, derived=self.derived)
        except (MotionSpaceError, OSError, ValueError, KeyError) as exc:
            raise BrokenSpace(f"motion space {name!r} cannot be read: {within(exc, self.directory)}") from exc
        entry = _Entry(stamp=stamp, space=space, bounds=quantisation_box(space))
        gc.freeze()  # a space lives as long as it is served: out of the collector's full passes
        with self._lock:
            # an older version stays open for connections already streaming it (mapped memory)
            self._entries[name] = entry
        return entry

    def get(self, name):
        """The open MotionSpace called ``name``."""
        return self._open(name).space

    def describe(self, name):
        """A JSON-ready description: sources, parameters (names, units, ranges), modes, sizes."""
        entry = self._open(name)
        space, meta = entry.space, entry.space.metadata
        pmap = space.parameter_map
        parameters = []
        if pmap is not None:
            for pname, unit, (lo, hi) in zip(pmap.names, pmap.units, pmap.domain()):
                parameters.append({"name": pname, "unit": unit, "min": lo, "max": hi, "default": (lo + hi) / 2})
        return {
            "name": space.name if space.name == name else name,
            "playable": pmap is not None,
            "cyclic": bool(space.cyclic),
            "n_vertices": int(space.n_vertices),
            "n_faces": int(len(space.faces)),
            "n_phases": int(space.n_phases),
            "model_size": float(space.model_size),
            "epsilon": float(meta.get("epsilon", 0.0)),
            "sources": [{"name": s["name"], "duration": float(s["duration"])} for s in meta["sources"]],
            "parameters": parameters,
            "layout": (meta.get("parameters") or {}).get("layout", {}).get("kind"),
            "modes": list(MODES),
            "bounds": entry.bounds.tolist(),
            "file_bytes": entry.stamp[2],
        }

    def close(self):
        with self._lock:
            for entry in self._entries.values():
                entry.space.close()
            self._entries.clear()
