"""What the run-time transition search compares: every node's samples of blend weights and
phases, and a short window of motion starting at each (shape and motion in one vector).

A node's samples are a regular grid of its parameter sheet (``per_axis`` points per axis of the
layout's coordinates u; one sample, equal weights, for a space without parameters) times ``M``
phases. The window at a sample is ``frames`` + 1 frames ``step`` seconds apart, played from that
phase at those weights: a subset of the vertices placed by the root's own motion relative to the
root at the window's start (so a walking window drifts forward and a standing one does not),
and their velocities. Two windows compare by the root mean square of their difference.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.blend.phase import phase_of_sample
from engine.graph.clock import NodeClock, move


@dataclass(frozen=True)
class WindowOptions:
    """How windows are sampled and compared.

    frames : int            frames in a window
    step : float            seconds between them
    vertices : int          vertices compared (an even spread of the mesh's indices)
    velocity_weight : float seconds: velocities count as displacements over this long
    phases : int            phase samples per node (at most the space's own)
    per_axis : int          parameter samples per axis of the sheet
    """

    frames: int = 6
    step: float = 1.0 / 30.0
    vertices: int = 300
    velocity_weight: float = 0.1
    phases: int = 24
    per_axis: int = 5

    def __post_init__(self):
        if not (2 <= self.frames <= 60 and 0 < self.step <= 0.5 and 10 <= self.vertices
                and self.velocity_weight >= 0 and 4 <= self.phases <= 256 and 1 <= self.per_axis <= 21):
            raise ValueError(f"window options out of range: {self}")


@dataclass
class NodeSamples:
    """A node's samples.

    u : (K, dims) float        sheet coordinates (dims 0 without parameters)
    weights : (K, N) float     blend weights
    params : (K, k) float      parameters the weights realise (k 0 without parameters)
    durations : (K,) float     seconds of a cycle (or clip) at each weights
    phases : (M,) float        phase samples
    """

    u: np.ndarray
    weights: np.ndarray
    params: np.ndarray
    durations: np.ndarray
    phases: np.ndarray


def node_samples(space, options):
    """The samples of a space's weights and phases (``NodeSamples``)."""
    pmap = space.parameter_map
    if pmap is None:
        u = np.zeros((1, 0))
        weights = np.full((1, space.n_sources), 1.0 / space.n_sources)
        params = np.zeros((1, 0))
    else:
        dims = pmap.layout.dims
        axis = np.linspace(0.0, 1.0, options.per_axis)
        u = np.stack(np.meshgrid(*[axis] * dims, indexing="ij"), axis=-1).reshape(-1, dims)
        weights = np.array([pmap.layout.weights(point) for point in u])
        params = np.array([pmap.at(point) for point in u])
    M = min(options.phases, space.n_phases)
    phases = np.array([phase_of_sample(j, M, space.cyclic) for j in range(M)])
    durations = np.array([space.root_track.duration(w) for w in weights])
    return NodeSamples(u=u, weights=weights, params=params, durations=durations, phases=phases)


def compared_vertices(n_vertices, count):
    """(count,) int: an even spread of vertex indices."""
    return np.unique(np.linspace(0, n_vertices - 1, min(count, n_vertices)).round().astype(np.int64))


def window(space, weights, phase, options, vertices):
    """(2 * frames * len(vertices) * 3,) float: the window starting at ``phase`` (module notes)."""
    clock = NodeClock(space, weights, phase)
    position, heading = np.zeros(3), 0.0
    placed = []
    for k in range(options.frames + 1):
        mesh = np.asarray(clock.mesh("linear"))[vertices]
        c, s = np.cos(heading), np.sin(heading)
        R = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        placed.append(mesh @ R.T + position)
        if k < options.frames:
            position, heading = move(position, heading, *clock.advance(options.step))
    placed = np.stack(placed)
    velocity = np.diff(placed, axis=0) / options.step
    return np.concatenate([placed[:-1].ravel(), options.velocity_weight * velocity.ravel()])


def node_windows(space, samples, options, vertices, progress=None):
    """(K, M, d) float32 windows at every sample."""
    K, M = len(samples.weights), len(samples.phases)
    out = None
    for k in range(K):
        for j in range(M):
            w = window(space, samples.weights[k], samples.phases[j], options, vertices)
            if out is None:
                out = np.empty((K, M, len(w)), dtype=np.float64)
            out[k, j] = w
        if progress:
            progress(k + 1, K)
    return out


def dissimilarity(windows_a, windows_b):
    """(KA, MA, KB, MB) float32: RMS difference (m) between every pair of windows.

    Notes
    -----
    |a - b|^2 = |a|^2 + |b|^2 - 2 a.b over all pairs at once, divided by the number of
    compared 3-vectors (positions and weighted velocities of every vertex in every frame).
    """
    KA, MA, d = windows_a.shape
    KB, MB, _ = windows_b.shape
    a = windows_a.reshape(-1, d)
    b = windows_b.reshape(-1, d)
    squared = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * (a @ b.T)
    rms = np.sqrt(np.maximum(squared, 0.0) / (d / 3))
    return rms.reshape(KA, MA, KB, MB).astype(np.float32)
