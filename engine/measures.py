"""Motion parameters measured on mesh sequences themselves (no skeleton needed).

These definitions are shared by the capture generator (to check what it made), the parameter
maps of motion spaces (to measure blended motions) and the evaluation:

- speed (m/s) and turn rate (deg/s) of a cyclic gait: from the centre of mass's displacement
  over one cycle; the chord of a circular path is corrected to arc length
- jump height (m): peak rise of the centre of mass above its height in the first frame
- jump distance (m): horizontal displacement of the centre of mass from the first to the last frame
- reach height (m): height of the centroid of a set of hand vertices at the frame where it is
  farthest from where it started (the peak of the reach, up or down)

The centre of mass is the volume centroid of the closed surface at uniform density.
"""

from __future__ import annotations

import numpy as np

from engine.surface import volume_centroid


def centre_of_mass(V, F):
    """(frames, 3) centre of mass of each frame of a closed-surface sequence (frames, n, 3)."""
    return volume_centroid(V, F)


def gait_speed_and_turn_rate(com, fps, frames_per_cycle):
    """Mean speed and turn rate of a cyclic gait from its centre-of-mass trajectory.

    Parameters
    ----------
    com : (frames, 3) float array   centre of mass per frame, frames >= frames_per_cycle + 1
    fps : float
    frames_per_cycle : int          N, the cycle length in frames

    Returns
    -------
    speed : float       m/s along the path
    turn_rate : float   deg/s about +Y, positive = turning left (towards +X from +Z)

    Notes
    -----
    Periodic in-cycle motion (bounce, sway) cancels in the displacement over a whole cycle. On a
    circular path the cycle chord c and the heading change theta give the arc length
    c * (theta / 2) / sin(theta / 2). theta comes from how fast the chord direction rotates.
    """
    com = np.asarray(com, dtype=float)
    N = int(frames_per_cycle)
    if len(com) < N + 1:
        raise ValueError(f"need at least {N + 1} frames for a cycle of {N}, got {len(com)}")
    period = N / fps
    chords = (com[N:] - com[:-N])[:, [0, 2]]
    length = np.linalg.norm(chords, axis=1).mean()
    angles = np.unwrap(np.arctan2(chords[:, 0], chords[:, 1]))
    if len(angles) >= 2:
        slope = np.polyfit(np.arange(len(angles)) / fps, angles, 1)[0]
    else:
        slope = 0.0
    theta = slope * period
    arc = length if abs(theta) < 1e-9 else length * (theta / 2) / np.sin(theta / 2)
    return float(arc / period), float(np.degrees(slope))


def jump_height(com):
    """Peak rise of the centre of mass above the first frame (m)."""
    com = np.asarray(com, dtype=float)
    return float(com[:, 1].max() - com[0, 1])


def jump_distance(com):
    """Horizontal centre-of-mass displacement from the first to the last frame (m)."""
    com = np.asarray(com, dtype=float)
    return float(np.linalg.norm((com[-1] - com[0])[[0, 2]]))


def reach_height(V, hand_vertices):
    """Height of the hand centroid at the peak of the reach (m).

    Parameters
    ----------
    V : (frames, n, 3) float array
    hand_vertices : (h,) int array   vertices of the reaching hand

    Returns
    -------
    height : float   y of the centroid of ``hand_vertices`` in the frame where that centroid is
                     farthest from its position in the first frame
    """
    hand = np.asarray(V)[:, hand_vertices].mean(axis=1)
    peak = np.argmax(np.linalg.norm(hand - hand[0], axis=1))
    return float(hand[peak, 1])
