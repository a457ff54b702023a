"""Loose garments for the studio body: a flared skirt and wide bell sleeves.

Each garment is a closed shell (an outer and an inner sheet joined at the hem and at the top,
topologically a torus) wrapped around a body part: its radius at every height and angle is the
body's own outline there, made monotone towards the hem, plus a clearance that grows towards
the hem (the flare). Garments are skinned to the body's joints (the top follows the waist or
the elbow, the hem partly follows the thighs) and carry a dynamics amplitude (0 at the top, 1 at
the hem) for the lagging spring motion added on top of skinning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

THICKNESS = 0.012  # shell thickness (m): thin cloth as a volumetric reconstruction sees it


@dataclass(frozen=True)
class Garment:
    """One garment shell.

    Attributes
    ----------
    name : str
    V : (n, 3) float array         rest vertices (outer sheet first, then inner)
    F : (m, 3) int array           outward-oriented triangles of a closed shell
    weight_index, weight : (n, 4) arrays   skin weights over the studio joints
    amplitude : (n,) float array   0 at the top, 1 at the hem: how much the garment lags
    u, s : (n,) float arrays       around (0..1) and down (0 top .. 1 hem) the garment
    """

    name: str
    V: np.ndarray
    F: np.ndarray
    weight_index: np.ndarray
    weight: np.ndarray
    amplitude: np.ndarray
    u: np.ndarray
    s: np.ndarray


def shell_faces(rings, sectors):
    """Triangles of a closed shell of two (rings x sectors) grids: outer sheet, inner sheet.

    Vertex (sheet, i, j) has index sheet * rings * sectors + i * sectors + j; ring 0 is the top.
    The outer sheet faces away from the axis, the inner towards it, the hem strip down and the
    top strip up (for a shell whose rings go down the -axis direction with angle increasing
    counter-clockwise seen from the top).
    """
    def idx(sheet, i, j):
        return sheet * rings * sectors + i * sectors + (j % sectors)

    i, j = np.meshgrid(np.arange(rings - 1), np.arange(sectors), indexing="ij")
    i, j = i.ravel(), j.ravel()
    quads = [np.stack([idx(0, i, j), idx(0, i + 1, j), idx(0, i + 1, j + 1), idx(0, i, j + 1)], 1),
             np.stack([idx(1, i, j), idx(1, i, j + 1), idx(1, i + 1, j + 1), idx(1, i + 1, j)], 1)]
    j = np.arange(sectors)
    last = rings - 1
    quads.append(np.stack([idx(0, last, j), idx(1, last, j), idx(1, last, j + 1), idx(0, last, j + 1)], 1))
    quads.append(np.stack([idx(0, 0, j), idx(0, 0, j + 1), idx(1, 0, j + 1), idx(1, 0, j)], 1))
    Q = np.concatenate(quads)
    return np.concatenate([Q[:, [0, 1, 2]], Q[:, [0, 2, 3]]])


def _outline(points, heights, angles, levels, sectors, band, spread=1):
    """Largest radius of ``points`` per (level, sector), dilated over neighbouring sectors."""
    radius = np.zeros((len(levels), sectors))
    sector = np.floor(angles / (2 * np.pi) * sectors).astype(int) % sectors
    for i, level in enumerate(levels):
        near = np.abs(heights - level) < band
        if np.any(near):
            np.maximum.at(radius[i], sector[near], points[near])
    dilated = radius.copy()
    for shift in range(1, spread + 1):
        dilated = np.maximum(dilated, np.maximum(np.roll(radius, shift, 1), np.roll(radius, -shift, 1)))
    return dilated


def _smooth_around(radius, passes=3):
    for _ in range(passes):
        radius = 0.25 * np.roll(radius, 1, 1) + 0.5 * radius + 0.25 * np.roll(radius, -1, 1)
    return radius


def _shell(centre, axis, e1, e2, levels, radius_inner, sectors):
    """Vertices of the two sheets about an axis: (2 * rings * sectors, 3)."""
    angle = 2 * np.pi * (np.arange(sectors) + 0.5) / sectors
    direction = np.cos(angle)[:, None] * e1 + np.sin(angle)[:, None] * e2  # (sectors, 3)
    out = []
    for radius in (radius_inner + THICKNESS, radius_inner):
        out.append(centre + levels[:, None, None] * axis + radius[:, :, None] * direction[None])
    return np.concatenate(out).reshape(-1, 3)


def skirt(V, weights_of, *, top, hem, rings, sectors, flare=0.09):
    """A flared skirt from the waist (height ``top``) to the hem (height ``hem``).

    Parameters
    ----------
    V : (n, 3) float array         rest body vertices (Y up, facing +Z)
    weights_of : callable(names) -> (n,) summed skin weight of the named joints
    top, hem : float               heights of the waistband and of the hem (m)
    rings, sectors : int           grid resolution of each sheet
    flare : float                  extra radius at the hem (m)

    Returns
    -------
    V_garment : (2 * rings * sectors, 3), F_garment, u, s : per-vertex parameters
    """
    keep = weights_of(("pelvis", "spine_01", "spine_02", "thigh_l", "thigh_r", "calf_l", "calf_r")) > 0.5
    P = V[keep]
    levels = np.linspace(top, hem, rings)
    angles = np.arctan2(P[:, 0], P[:, 2]) % (2 * np.pi)  # 0 = front (+Z), increasing towards +X
    radial = np.hypot(P[:, 0], P[:, 2])
    band = 0.6 * abs(top - hem) / (rings - 1) + 0.01
    outline = _outline(radial, P[:, 1], angles, levels, sectors, band)
    outline = np.maximum.accumulate(outline, axis=0)  # monotone down: drapes over the hips
    s = np.linspace(0.0, 1.0, rings)
    inner = _smooth_around(outline) + 0.004 + flare * s[:, None] ** 1.5
    # Angle increases from +Z towards +X: seen from the top (looking down -Y) that is clockwise,
    # so the rings run along -Y with e1 = +Z and e2 = +X, giving outward-facing outer sheets.
    centre = np.zeros(3)
    Vg = _shell(centre, np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]),
                levels, inner, sectors)
    return Vg, shell_faces(rings, sectors), *_grid_parameters(rings, sectors)


def sleeve(V, weights_of, elbow, wrist, *, rings, sectors, beyond=0.0, above=0.04, flare=0.045):
    """A wide bell sleeve around the forearm from just above the elbow to past the wrist.

    Parameters
    ----------
    V : (n, 3) float array      rest body vertices
    weights_of : callable(names) -> (n,)
    elbow, wrist : (3,) float arrays   rest joint positions of this arm
    beyond, above : float       how far the sleeve reaches past the wrist and above the elbow (m)
    flare : float               extra radius at the cuff (m)

    Returns
    -------
    V_garment, F_garment, u, s   as for ``skirt``
    """
    side = "l" if elbow[0] > 0 else "r"
    axis = wrist - elbow
    length = np.linalg.norm(axis)
    axis = axis / length
    e1 = np.cross(axis, np.array([0.0, 0.0, 1.0]))
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    keep = weights_of((f"upperarm_{side}", f"lowerarm_{side}")) > 0.5
    P = V[keep] - elbow
    along = P @ axis
    a1, a2 = P @ e1, P @ e2
    radial = np.hypot(a1, a2)
    close = radial < 0.09
    levels = np.linspace(-above, length + beyond, rings)
    angles = np.arctan2(a2, a1) % (2 * np.pi)
    band = 0.6 * (length + above + beyond) / (rings - 1) + 0.005
    outline = _outline(radial[close], along[close], angles[close], levels, sectors, band)
    outline = np.maximum.accumulate(np.maximum(outline, 0.02), axis=0)
    s = np.linspace(0.0, 1.0, rings)
    inner = _smooth_around(outline) + 0.004 + flare * s[:, None] ** 1.5
    # Rings run along +axis; with (e1, e2, axis) right handed the angle runs counter-clockwise
    # seen from the elbow, which is what shell_faces expects of rings running along -axis when
    # e1 and e2 are swapped.
    Vg = _shell(elbow, axis, e2, e1, levels, inner, sectors)
    return Vg, shell_faces(rings, sectors), *_grid_parameters(rings, sectors)


def _grid_parameters(rings, sectors):
    s = np.repeat(np.linspace(0.0, 1.0, rings), sectors)
    u = np.tile((np.arange(sectors) + 0.5) / sectors, rings)
    return np.concatenate([u, u]), np.concatenate([s, s])


def limb_capsules(V, weight_of_bone, skeleton, bones):
    """Tapered capsules around limb bones at rest: (head joint, tail joint, head radius, tail radius).

    The radius at each end is the median distance from the bone of the vertices the bone owns
    near that end (its outer third), plus 5 mm: limbs are not round, and cloth pushed by a limb
    rests on its widest side.
    """
    capsules = []
    for bone, tail_joint in bones:
        j, k = skeleton.index(bone), skeleton.index(tail_joint)
        A, B = skeleton.rest[j], skeleton.rest[k]
        own = V[weight_of_bone(bone) > 0.5]
        t = (own - A) @ (B - A) / ((B - A) @ (B - A))
        d = np.linalg.norm(own - (A + np.clip(t, 0.0, 1.0)[:, None] * (B - A)), axis=1)
        ends = [(t > 0.0) & (t < 1 / 3), (t > 2 / 3) & (t < 1.0)]
        r0, r1 = (float(np.median(d[end] if np.any(end) else d)) + 0.005 for end in ends)
        capsules.append((j, k, r0, r1))
    return tuple(capsules)


def push_out_of_capsules(P, heads, tails, radii, clearance):
    """Move points out of tapered capsules (cloth pushed aside by the legs).

    Parameters
    ----------
    P : (frames, m, 3) float array   garment points (changed in place and returned)
    heads, tails : (frames, c, 3)    capsule ends per frame
    radii : (c, 2) float array       radius at the head and at the tail
    clearance : (m,) float array     how far outside the capsule each point must stay

    Returns
    -------
    P : (frames, m, 3) float array
    """
    for c in range(heads.shape[1]):
        A, B = heads[:, c][:, None], tails[:, c][:, None]
        AB = B - A
        t = np.clip(np.sum((P - A) * AB, axis=-1) / np.maximum(np.sum(AB * AB, axis=-1), 1e-12), 0.0, 1.0)
        Q = A + t[..., None] * AB
        offset = P - Q
        d = np.linalg.norm(offset, axis=-1)
        r = radii[c, 0] + t * (radii[c, 1] - radii[c, 0]) + clearance
        inside = (d < r) & (d > 1e-9)
        scale = np.where(inside, r / np.maximum(d, 1e-9), 1.0)
        P = Q + offset * scale[..., None]
    return P
