"""Root motion: split mesh frames into a root transform and root-local meshes (DESIGN.md step 6).

The root is a horizontal translation plus a heading (rotation about +Y) per frame, estimated
from the mesh alone, so it works on any captured sequence:

- translation: the horizontal centre of mass, low-pass filtered (over one cycle for cyclic
  motion, which removes the in-cycle sway exactly; over a short window for clips);
- heading: the rotation about +Y that best maps a reference shape onto each frame, weighted
  towards vertices that stay put relative to the body (the torso); filtered over one cycle for
  cyclic motion, and interpolated between the settled start and end poses of one-shot clips.

Root-local frames have the root translation removed and are rotated into the root's heading,
so blending never averages world positions of different trajectories. Per frame the root's
velocity in its own frame and its turn rate are what a player integrates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.rotations import rot_y
from engine.surface import volume_centroid


@dataclass(frozen=True)
class RootMotion:
    """A sequence split into root transforms and root-local meshes.

    Attributes
    ----------
    position : (frames, 3) float array   root on the ground plane (y = 0)
    heading : (frames,) float array      radians about +Y relative to the first frame's facing
    local : (frames, n, 3) float array   root-local vertices: R_y(-heading) (V - position)
    fps : float
    """

    position: np.ndarray
    heading: np.ndarray
    local: np.ndarray
    fps: float

    def velocity(self):
        """(frames, 3) root velocity in the root's own frame (m/s), central differences."""
        world = np.gradient(self.position, 1.0 / self.fps, axis=0)
        return np.einsum("fba,fb->fa", rot_y(self.heading), world)

    def turn_rate(self):
        """(frames,) heading rate in rad/s."""
        return np.gradient(self.heading, 1.0 / self.fps)

    def world(self, local=None):
        """World vertices from root-local ones (default: this sequence's)."""
        local = self.local if local is None else local
        return np.einsum("fab,fnb->fna", rot_y(self.heading), local) + self.position[:, None, :]


def _moving_average(x, window, periodic=False):
    """Centred moving average along axis 0 that spans exactly ``window`` samples.

    Odd windows use a box of ``window`` taps; even ones the trapezoid [1/2, 1, ..., 1, 1/2] /
    window (window + 1 taps). Either sums exactly one period of a signal periodic in
    ``window`` samples, so it removes a periodic component exactly while staying centred.
    Ends are extended linearly (a constant velocity passes unbiased) or, with ``periodic`` and at
    least window + 1 samples, by the neighbouring period plus one period's trend, which is exact
    for a periodic signal on a linear trend (a steady gait's heading, say).
    """
    x = np.asarray(x, dtype=float)
    window = int(window)
    if window <= 1 or len(x) < 2:
        return x.copy()
    if window % 2:
        kernel = np.ones(window) / window
    else:
        kernel = np.ones(window + 1)
        kernel[0] = kernel[-1] = 0.5
        kernel /= window
    half = len(kernel) // 2
    flat = x.reshape(len(x), -1)
    n = len(flat)
    if periodic and n > window:
        trend_head = flat[window] - flat[0]
        trend_tail = flat[n - 1] - flat[n - 1 - window]
        head = flat[window - half:window] - trend_head
        tail = flat[n - window:n - window + half] + trend_tail
        if len(head) < half or len(tail) < half:
            periodic = False
    if not (periodic and n > window):
        steps = np.arange(half, 0, -1)[:, None]
        head = flat[0] - (flat[1] - flat[0]) * steps
        tail = flat[-1] + (flat[-1] - flat[-2]) * np.arange(1, half + 1)[:, None]
    padded = np.concatenate([head, flat, tail])
    out = np.stack([np.correlate(padded[:, c], kernel, mode="valid") for c in range(flat.shape[1])], axis=1)
    return out.reshape(x.shape)


def _stability_weights(centred):
    """Per-vertex weights favouring vertices whose body-relative position varies little."""
    spread = np.linalg.norm(centred - centred.mean(axis=0), axis=2).mean(axis=0)
    return 1.0 / (spread + 0.01 * (spread.max() + 1e-12))


def _yaw_between(A, B, weights):
    """Angle about +Y of the weighted best rotation taking points A onto B.

    Both point sets are centred at their weighted centroids first (weighted Procrustes), so a
    shift of the heavily weighted points (a forward lean) does not read as a turn.
    """
    total = weights.sum()
    a = A[:, [0, 2]] - (weights @ A[:, [0, 2]]) / total
    b = B[:, [0, 2]] - (weights @ B[:, [0, 2]]) / total
    # For rotation R_y(t): x' = x cos t + z sin t, z' = -x sin t + z cos t.
    cos_term = np.sum(weights * (a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1]))
    sin_term = np.sum(weights * (a[:, 1] * b[:, 0] - a[:, 0] * b[:, 1]))
    return float(np.arctan2(sin_term, cos_term))


def estimate_root_motion(V, F, fps, *, period=None, smoothing=0.3, reference=None):
    """Split a mesh sequence into root transforms and root-local meshes.

    Parameters
    ----------
    V : (frames, n, 3) float array   consistent-topology frames (world, Y up)
    F : (m, 3) int array             faces of a closed surface (for the centre of mass)
    fps : float
    period : float or None           cycle length in frames of a cyclic motion: filter over it
    smoothing : float                filter window in seconds for non-cyclic clips
    reference : (n, 3) float array or None
        the shape whose facing is heading 0 (a space's rest mesh, so all its sources share one
        forward direction); default: the first frame

    Returns
    -------
    RootMotion

    Notes
    -----
    The heading is filtered first; the centre of mass's velocity is then expressed in that
    rotating frame, where a steady gait's velocity is periodic even when turning, filtered
    there (so a circular path keeps its radius and speed) and integrated back to positions,
    offset to follow the centre of mass on average.
    """
    V = np.asarray(V, dtype=np.float64)
    frames = len(V)
    if frames < 2:
        raise ValueError(f"root motion needs at least 2 frames, got {frames}")
    com = volume_centroid(V, F)
    window = int(round(period)) if period is not None else max(1, int(round(smoothing * fps)))
    window = min(window, frames - 1)

    centred = V - com[:, None, :]
    weights = _stability_weights(centred)
    if reference is None:
        base = centred[0]
    else:
        reference = np.asarray(reference, dtype=np.float64)
        base = reference - reference.mean(axis=0)
    raw = np.unwrap([_yaw_between(base, centred[k], weights) for k in range(frames)])
    periodic = period is not None
    if periodic:
        heading = _moving_average(raw, window, True)
    else:
        # One-shot clips start and end in a settled pose, while in between the whole body may
        # twist and bend (a reach, a jump's arm swing): the heading goes linearly from the
        # start pose's to the end pose's (still following a clip that turns as a whole).
        k = max(1, min(frames // 4, int(round(0.2 * fps))))
        start, end = raw[:k].mean(), raw[-k:].mean()
        heading = start + (end - start) * np.linspace(0.0, 1.0, frames)

    ground = com.copy()
    ground[:, 1] = 0.0
    # Per-step displacements in the root frame (heading at the step's middle) are periodic for a
    # steady gait, turning or not: filter them there, then integrate back.
    middle = 0.5 * (heading[1:] + heading[:-1])
    steps = np.einsum("fba,fb->fa", rot_y(middle), np.diff(ground, axis=0))
    steps = _moving_average(steps, window, periodic)
    position = np.zeros_like(ground)
    position[1:] = np.cumsum(np.einsum("fab,fb->fa", rot_y(middle), steps), axis=0)
    position += (ground - position).mean(axis=0)
    position[:, 1] = 0.0
    local = np.einsum("fba,fnb->fna", rot_y(heading), V - position[:, None, :])
    return RootMotion(position=position, heading=heading, local=local, fps=float(fps))


FACING_TOLERANCE = np.radians(1.0)  # a reference facing off the travel by less is left as it is
FORWARD_CONE = np.radians(30.0)     # sources travelling within this of their facing say where forward is
MOVING = 0.05                       # mean speed, in model sizes per second, of a source that travels


def travel_turn(roots, size):
    """The turn about +Y (radians) from the heading reference's facing to the way the sources
    travel, or 0 when they do not say or it is under 1 degree.

    A space's heading 0 is its rest mesh's facing. The generator's rest faces exactly forward; a
    captured one (an aligned capture's root frame, mid-stride) may face a few degrees off the way
    the body walks, and the space then walked that much to the side of its facing (5.6 degrees on
    the tiny preset's walk and run aligned and built; a docs-only user). Every source whose mean
    velocity in its root frame is over ``MOVING`` model sizes per second and within ``FORWARD_CONE``
    of its facing gives that velocity's angle (sidesteps and backward walks say nothing); the
    turn is their median.

    Parameters
    ----------
    roots : list of RootMotion    size : float, the model size (m)
    """
    angles = []
    for root in roots:
        v = root.velocity().mean(axis=0)
        if np.hypot(v[0], v[2]) > MOVING * size:
            angle = float(np.arctan2(v[0], v[2]))  # from +Z towards +X, as rot_y turns
            if abs(angle) < FORWARD_CONE:
                angles.append(angle)
    turn = float(np.median(angles)) if angles else 0.0
    return turn if abs(turn) >= FACING_TOLERANCE else 0.0


def turned_reference(rest, turn):
    """The heading reference for a ``travel_turn`` of ``turn``: ``rest`` (n, 3) turned by ``-turn``
    about +Y through its mean, against which the root-local frames' velocity points along +Z."""
    rest = np.asarray(rest, dtype=np.float64)
    centre = rest.mean(axis=0)
    return (rest - centre) @ rot_y(-turn).T + centre
