"""A loaded motion space: memory-mapped arrays and the blenders built on them."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from engine.blend import (
    Corrections,
    HybridBlender,
    LinearBlender,
    NonlinearBlender,
    PhasedNonlinearBlender,
    SimplexTree,
    VolumetricEmbedding,
)
from engine.blend.cache import PhaseTableBlender
from engine.blend.hybrid import hybrid_layout
from engine.blend.nonlinear import component_major_layout
from engine.motion_space.build import SPACE_FORMAT, SPACE_VERSION
from engine.motion_space.container import Container, MotionSpaceError
from engine.parameters import ParameterMap, RootTrack

MODES = ("linear", "hybrid", "nonlinear")
# What a derived file of each kind holds; bump one when hybrid_layout or component_major_layout
# change what they return, so older derived files are built again.
LAYOUT_VERSIONS = {"hybrid": 1, "nonlinear": 1}


class MotionSpace:
    """A motion space opened from its ``.mspace`` file.

    ``space = MotionSpace.open(path)`` maps the file (no copies); ``space.blender(mode)`` builds
    a blender once and caches it; ``space.blend(weights, phase, mode)`` is a convenience.
    ``MotionSpace.open(path, derived=DerivedStore(directory))``: the arrays the hybrid and
    non-linear blenders derive from the file are mapped from files in ``directory`` too (built
    there once), so that processes serving the same space share them (motion_space/derived.py).

    Attributes
    ----------
    name : str
    metadata : dict
    faces : (m, 3) int32 array
    sources : (P, N, n, 3) float32 array   phase-major, root-local
    n_sources, n_phases, n_vertices : int
    cyclic : bool
    model_size : float                     metres
    """

    def __init__(self, container, derived=None):
        self.container = container
        self.derived = derived
        meta = container.metadata
        if meta.get("format") != SPACE_FORMAT:
            raise MotionSpaceError(f"{container.path}: the file holds {meta.get('format')!r}, "
                                   f"not a {SPACE_FORMAT}")
        if meta.get("version", 0) != SPACE_VERSION:
            newer = meta.get("version", 0) > SPACE_VERSION
            raise MotionSpaceError(f"{container.path}: motion space version {meta.get('version')} "
                                   + ("is newer than this morphspace understands" if newer else
                                      "is from an older morphspace; rebuild the space")
                                   + f" (this morphspace reads version {SPACE_VERSION})")
        self.metadata = meta
        self.name = meta["name"]
        self.n_sources, self.n_phases = meta["n_sources"], meta["n_phases"]
        self.n_vertices = meta["n_vertices"]
        self.cyclic = meta["cyclic"]
        self.model_size = meta["model_size"]
        self.faces = container["faces"]
        self.sources = container["sources"]
        self._blenders = {}
        self._layouts = []

    @classmethod
    def open(cls, path, *, verify=True, derived=None):
        """Open a motion space file (``verify`` checks every array's checksum); ``derived``: a
        DerivedStore for the blenders' derived arrays (None: each blender makes its own)."""
        return cls(Container.open(path, verify=verify), derived)

    def close(self):
        self.container.close()
        for layout in self._layouts:
            layout.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @property
    def source_names(self):
        return [s["name"] for s in self.metadata["sources"]]

    @cached_property
    def root_track(self):
        """Blendable root motion (durations, root displacement and turn per unit phase)."""
        c = self.container
        return RootTrack(durations=np.asarray(c["durations"]), root_rate=np.asarray(c["root_rate"]),
                         turn_rate=np.asarray(c["turn_rate"]), cyclic=self.cyclic)

    @cached_property
    def parameter_map(self):
        """The ParameterMap of the space's high-level parameters, or None."""
        meta = self.metadata.get("parameters")
        if not meta:
            return None
        c = self.container
        return ParameterMap.from_stored(meta, c["parameter_values"], c["parameter_axis"])

    @property
    def effector(self):
        """(h,) vertices that move most in the sources (a reach's hand)."""
        return np.asarray(self.container["effector"])

    def durations(self):
        """(N,) seconds per source (one cycle, or the whole clip)."""
        return np.asarray(self.container["durations"])

    @cached_property
    def embedding(self):
        c = self.container
        return VolumetricEmbedding(V_tet=np.asarray(c["tet_vertices"]), T=np.asarray(c["tets"], dtype=np.int64),
                                   surface_tet=np.asarray(c["surface_tet"], dtype=np.int64),
                                   surface_bary=np.asarray(c["surface_bary"]))

    @cached_property
    def tree(self):
        c = self.container
        return SimplexTree.from_arrays(np.asarray(c["hybrid_references"]), np.asarray(c["hybrid_cells"]),
                                       np.asarray(c["hybrid_children"]), np.asarray(c["hybrid_split"]))

    @cached_property
    def corrections(self):
        c = self.container
        return Corrections.from_arrays(self.n_phases, self.n_vertices,
                                       {key: c[f"corrections_{key}"]
                                        for key in ("pointer", "vertex", "mask", "value", "scale")})

    def blender(self, mode):
        """The blender for ``mode`` ("linear", "hybrid" or "nonlinear"), built once."""
        if mode not in self._blenders:
            self._blenders[mode] = self.new_blender(mode)
        return self._blenders[mode]

    def new_blender(self, mode):
        """A blender for ``mode`` of the caller's own (blenders keep scratch buffers: a thread
        that blends beside another needs its own). Built anew on every call."""
        if mode not in MODES:
            raise ValueError(f"unknown blend mode {mode!r}; choose one of {', '.join(MODES)}")
        c = self.container
        if mode == "linear":
            return LinearBlender(self.sources, self.cyclic)
        if mode == "hybrid":
            layout = self._layout("hybrid", lambda: hybrid_layout(self.corrections, self.n_vertices))
            return HybridBlender(self.sources, self.tree, self.corrections, self.cyclic, layout=layout)
        q, s, d = c["nl_quaternions"], c["nl_stretch"], c["nl_detail"]
        layout = self._layout("nonlinear", lambda: component_major_layout(q, s, d))
        inner = NonlinearBlender(self.embedding, q, s, d, self.sources.reshape(-1, self.n_vertices, 3), layout=layout)
        return PhasedNonlinearBlender(inner, self.n_phases, self.n_sources, self.cyclic)

    def _layout(self, kind, build):
        """A blender's derived arrays: mapped from the DerivedStore, or None (the blender makes
        them itself)."""
        if self.derived is None:
            return None
        layout = self.derived.load(self.container, kind, {"version": LAYOUT_VERSIONS[kind]}, build)
        self._layouts.append(layout)
        return layout

    def frame_blender(self, mode):
        """The blender a player uses: linear and hybrid with phase tables (exact; one
        interpolation per frame at weights that recur), non-linear as it is. Built once."""
        key = f"{mode}:tables"
        if key not in self._blenders:
            blender = self.blender(mode)
            if mode != "nonlinear":
                blender = PhaseTableBlender(blender, self.n_phases, self.cyclic)
            self._blenders[key] = blender
        return self._blenders[key]

    def check_weights(self, weights):
        """Validated (N,) float weights: finite, non-negative, not all zero."""
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (self.n_sources,):
            raise ValueError(f"{self.name}: expected {self.n_sources} weights "
                             f"({', '.join(self.source_names)}), got shape {w.shape}")
        if not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"{self.name}: weights must be finite, non-negative and not all zero, got {w.tolist()}")
        return w

    def blend(self, weights, phase, mode="hybrid"):
        """(n, 3) blended vertices at ``weights`` and ``phase`` in [0, 1]."""
        phase = float(phase)
        if not np.isfinite(phase):
            raise ValueError(f"{self.name}: phase must be finite, got {phase}")
        return self.blender(mode).blend(self.check_weights(weights), phase)
