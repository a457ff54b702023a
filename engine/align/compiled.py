"""The alignment's inner loops, compiled (numba).

- :func:`closest_among_faces`: closest points on a triangle mesh among given candidate faces.
  The correspondence searches of an alignment ask this about 90 times per pair of 10,000-vertex
  frames, for 3,000-10,000 points and 6 candidate faces each: as numpy array operations
  (:func:`engine.surface.closest_on_triangles`) it was about a third of the aligner's CPU; a loop
  over the points that keeps each point's candidates in registers is about ten times faster. The
  region tests are Ericson's ("Real-Time Collision Detection", section 5.1.5); the nearest
  candidate wins, the first of equals.
- :func:`colour_choice`: the colour cues' choice among a match's 17 candidates
  (:func:`engine.align.matching.colour_flow`), one point at a time.
- :func:`rotation_fit_compiled`: :func:`engine.align.rigid.rotation_fit`'s iteration, one matrix
  at a time.
- :func:`patch_normal_equations`: the per-patch sums of :func:`engine.align.rigid.patch_rigid_steps`.

Compiled on first use (about 3 s) and cached on disk (:func:`engine.jit.compiled` says where).
"""

from __future__ import annotations

import numpy as np

from engine.jit import compiled as _compiled


@_compiled
def _closest_among(P, V, F, faces):  # pragma: no cover (compiled; tested through closest_among_faces)
    q, k = faces.shape
    points = np.empty((q, 3))
    bary = np.empty((q, 3))
    dist = np.empty(q)
    best_face = np.full(q, -1, dtype=np.int64)
    for i in range(q):
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        best = np.inf
        for j in range(k):
            f = faces[i, j]
            if f < 0:
                continue
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            ax, ay, az = V[a, 0], V[a, 1], V[a, 2]
            bx, by, bz = V[b, 0], V[b, 1], V[b, 2]
            cx, cy, cz = V[c, 0], V[c, 1], V[c, 2]
            abx, aby, abz = bx - ax, by - ay, bz - az
            acx, acy, acz = cx - ax, cy - ay, cz - az
            apx, apy, apz = px - ax, py - ay, pz - az
            d1 = abx * apx + aby * apy + abz * apz
            d2 = acx * apx + acy * apy + acz * apz
            if d1 <= 0.0 and d2 <= 0.0:
                u, v, w = 1.0, 0.0, 0.0
            else:
                bpx, bpy, bpz = px - bx, py - by, pz - bz
                d3 = abx * bpx + aby * bpy + abz * bpz
                d4 = acx * bpx + acy * bpy + acz * bpz
                if d3 >= 0.0 and d4 <= d3:
                    u, v, w = 0.0, 1.0, 0.0
                else:
                    vc = d1 * d4 - d3 * d2
                    # an edge region needs the edge (its squared length > 0): a face that repeats a
                    # corner is the segment between its other two, found by the regions after
                    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 > 0.0:
                        t = d1 / (d1 - d3)
                        u, v, w = 1.0 - t, t, 0.0
                    else:
                        cpx, cpy, cpz = px - cx, py - cy, pz - cz
                        d5 = abx * cpx + aby * cpy + abz * cpz
                        d6 = acx * cpx + acy * cpy + acz * cpz
                        if d6 >= 0.0 and d5 <= d6:
                            u, v, w = 0.0, 0.0, 1.0
                        else:
                            vb = d5 * d2 - d1 * d6
                            if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 > 0.0:
                                t = d2 / (d2 - d6)
                                u, v, w = 1.0 - t, 0.0, t
                            else:
                                va = d3 * d6 - d5 * d4
                                if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and (d4 - d3) + (d5 - d6) > 0.0:
                                    t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                                    u, v, w = 0.0, 1.0 - t, t
                                else:
                                    denom = va + vb + vc
                                    if denom != 0.0:
                                        v = vb / denom
                                        w = vc / denom
                                        u = 1.0 - v - w
                                    else:  # a degenerate face: its centre
                                        u = v = w = 1.0 / 3.0
            x = u * ax + v * bx + w * cx
            y = u * ay + v * by + w * cy
            z = u * az + v * bz + w * cz
            d = (x - px) * (x - px) + (y - py) * (y - py) + (z - pz) * (z - pz)
            if d < best:
                best = d
                best_face[i] = f
                points[i, 0], points[i, 1], points[i, 2] = x, y, z
                bary[i, 0], bary[i, 1], bary[i, 2] = u, v, w
        if best_face[i] < 0:  # no candidate: the point stays, infinitely far
            points[i, 0], points[i, 1], points[i, 2] = px, py, pz
            bary[i, 0], bary[i, 1], bary[i, 2] = 1.0, 0.0, 0.0
        dist[i] = np.sqrt(best)
    return points, dist, best_face, bary


def closest_among_faces(P, V, F, faces):
    """Per point, the closest point on the nearest of its candidate faces.

    Parameters
    ----------
    P : (q, 3) float array      query points
    V : (n, 3) float array      mesh vertices
    F : (m, 3) int array        mesh faces
    faces : (q, k) int array    candidate faces of each point (-1: none)

    Returns
    -------
    points : (q, 3)   distance : (q,)   face : (q,) int64 (-1 where a point had no candidate)
    bary : (q, 3) barycentric coordinates of the point in its face
    """
    P = np.ascontiguousarray(P, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(len(P), -1)
    return _closest_among(P, np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(F, dtype=np.int64),
                          faces)


@_compiled
def _colour_choice(y, m, face, bary, idx, TV, TF, TN, TC, wanted, sigma2, reach):  # pragma: no cover
    p, k = idx.shape
    shift = np.zeros((p, 3))
    strength = np.zeros(p)
    for i in range(p):
        f = face[i]
        here = np.empty(3)
        for c in range(3):
            here[c] = bary[i, 0] * TC[TF[f, 0], c] + bary[i, 1] * TC[TF[f, 1], c] + bary[i, 2] * TC[TF[f, 2], c]
        base = ((here[0] - wanted[i, 0]) ** 2 + (here[1] - wanted[i, 1]) ** 2
                + (here[2] - wanted[i, 2]) ** 2) / sigma2
        best, best_j, middle = base, -1, False
        for half in range(2):  # the vertices first, then the midpoints (ties: the earlier wins)
            for j in range(k):
                v = idx[i, j]
                if TN[v, 0] * m[i, 0] + TN[v, 1] * m[i, 1] + TN[v, 2] * m[i, 2] <= 0.5:
                    continue
                colour, reach2 = 0.0, 0.0
                for c in range(3):
                    there = TC[v, c] if half == 0 else 0.5 * (here[c] + TC[v, c])
                    colour += (there - wanted[i, c]) ** 2
                    gap = TV[v, c] - y[i, c] if half == 0 else 0.5 * (y[i, c] + TV[v, c]) - y[i, c]
                    reach2 += gap * gap
                score = colour / sigma2 + reach2 / reach
                if score < best:
                    best, best_j, middle = score, j, half == 1
        gain = base - best
        strength[i] = gain / (gain + 1.0)
        if best_j >= 0:
            v = idx[i, best_j]
            along = 0.0
            for c in range(3):
                chosen = 0.5 * (y[i, c] + TV[v, c]) if middle else TV[v, c]
                shift[i, c] = chosen - y[i, c]
                along += shift[i, c] * m[i, c]
            for c in range(3):
                shift[i, c] -= along * m[i, c]
    return shift, strength


def colour_choice(y, m, face, bary, neighbours, target, colours, sigma, reach):
    """The colour cues' tangential shifts and strengths (see :func:`engine.align.matching.colour_flow`).

    Parameters
    ----------
    y, m : (p, 3) matches on the target and the target's normals there
    face, bary : (p,), (p, 3) the face each match lies on and its barycentric coordinates
    neighbours : (p, k) int   the target vertices nearest each match
    target : TargetSurface with colours     colours : (p, 3) the source points' colours
    sigma : float   the colour distance scale     reach : float   the squared distance scale

    Returns
    -------
    shift : (p, 3) tangential shifts     strength : (p,) in [0, 1)
    """
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _colour_choice(f64(y), f64(m), np.ascontiguousarray(face, dtype=np.int64), f64(bary),
                          np.ascontiguousarray(neighbours, dtype=np.int64), target.V, target.F, target.normals,
                          f64(target.colors), f64(colours), float(sigma) ** 2, float(reach))


@_compiled
def _rotation_fit(R, F, iterations):  # pragma: no cover (compiled; tested through rotation_fit)
    out = np.empty_like(R)
    for k in range(len(R)):
        r00, r01, r02 = R[k, 0, 0], R[k, 0, 1], R[k, 0, 2]
        r10, r11, r12 = R[k, 1, 0], R[k, 1, 1], R[k, 1, 2]
        r20, r21, r22 = R[k, 2, 0], R[k, 2, 1], R[k, 2, 2]
        f00, f01, f02 = F[k, 0, 0], F[k, 0, 1], F[k, 0, 2]
        f10, f11, f12 = F[k, 1, 0], F[k, 1, 1], F[k, 1, 2]
        f20, f21, f22 = F[k, 2, 0], F[k, 2, 1], F[k, 2, 2]
        for _ in range(iterations):
            # omega = sum_j r_j x f_j / (|r . f| + eps) over the columns j
            wx = (r10 * f20 - r20 * f10) + (r11 * f21 - r21 * f11) + (r12 * f22 - r22 * f12)
            wy = (r20 * f00 - r00 * f20) + (r21 * f01 - r01 * f21) + (r22 * f02 - r02 * f22)
            wz = (r00 * f10 - r10 * f00) + (r01 * f11 - r11 * f01) + (r02 * f12 - r12 * f02)
            dot = (r00 * f00 + r01 * f01 + r02 * f02 + r10 * f10 + r11 * f11 + r12 * f12
                   + r20 * f20 + r21 * f21 + r22 * f22)
            scale = abs(dot) + 1e-9
            wx, wy, wz = wx / scale, wy / scale, wz / scale
            angle = np.sqrt(wx * wx + wy * wy + wz * wz)
            norm = angle if angle > 0 else 1.0
            x, y, z = wx / norm, wy / norm, wz / norm
            c, s = np.cos(angle), np.sin(angle)
            u = 1.0 - c
            q00, q01, q02 = c + x * x * u, x * y * u - z * s, x * z * u + y * s
            q10, q11, q12 = y * x * u + z * s, c + y * y * u, y * z * u - x * s
            q20, q21, q22 = z * x * u - y * s, z * y * u + x * s, c + z * z * u
            r00, r10, r20 = q00 * r00 + q01 * r10 + q02 * r20, q10 * r00 + q11 * r10 + q12 * r20, \
                q20 * r00 + q21 * r10 + q22 * r20
            r01, r11, r21 = q00 * r01 + q01 * r11 + q02 * r21, q10 * r01 + q11 * r11 + q12 * r21, \
                q20 * r01 + q21 * r11 + q22 * r21
            r02, r12, r22 = q00 * r02 + q01 * r12 + q02 * r22, q10 * r02 + q11 * r12 + q12 * r22, \
                q20 * r02 + q21 * r12 + q22 * r22
        out[k, 0, 0], out[k, 0, 1], out[k, 0, 2] = r00, r01, r02
        out[k, 1, 0], out[k, 1, 1], out[k, 1, 2] = r10, r11, r12
        out[k, 2, 0], out[k, 2, 1], out[k, 2, 2] = r20, r21, r22
    return out


def rotation_fit_compiled(F, R0, iterations):
    """:func:`engine.align.rigid.rotation_fit`'s iteration, one matrix at a time."""
    return _rotation_fit(np.ascontiguousarray(R0, dtype=np.float64), np.ascontiguousarray(F, dtype=np.float64),
                         int(iterations))


@_compiled
def _patch_normal_equations(p, r, M, W, tangential, labels, count):  # pragma: no cover (compiled)
    H = np.zeros((count, 6, 6))
    g = np.zeros((count, 6))
    J = np.zeros((3, 6))
    metric = np.empty((3, 3))
    JtM = np.empty((6, 3))
    for q in range(len(p)):
        w, tau = W[q], tangential[q]
        for i in range(3):
            for j in range(3):
                mm = M[q, i] * M[q, j]
                metric[i, j] = w * (mm + tau * ((1.0 if i == j else 0.0) - mm))
        # x - y = (p + c - y) + [-[p]x  I] [omega; shift]
        J[0, 1], J[0, 2], J[0, 3] = p[q, 2], -p[q, 1], 1.0
        J[1, 0], J[1, 2], J[1, 4] = -p[q, 2], p[q, 0], 1.0
        J[2, 0], J[2, 1], J[2, 5] = p[q, 1], -p[q, 0], 1.0
        for i in range(6):
            for l in range(3):
                JtM[i, l] = J[0, i] * metric[0, l] + J[1, i] * metric[1, l] + J[2, i] * metric[2, l]
        k = labels[q]
        for i in range(6):
            for j in range(6):
                H[k, i, j] += JtM[i, 0] * J[0, j] + JtM[i, 1] * J[1, j] + JtM[i, 2] * J[2, j]
            g[k, i] += JtM[i, 0] * r[q, 0] + JtM[i, 1] * r[q, 1] + JtM[i, 2] * r[q, 2]
    return H, g


def patch_normal_equations(p, r, M, W, tangential, labels, count):
    """Per patch, the 6x6 normal matrix and the 6-vector of :func:`engine.align.rigid.patch_rigid_steps`.

    Parameters
    ----------
    p : (q, 3) points relative to their patch's centre     r : (q, 3) residuals P - Y
    M : (q, 3) unit normals     W, tangential : (q,) weights     labels : (q,) patch of each point
    count : int number of patches

    Returns
    -------
    H : (count, 6, 6)     g : (count, 6)   sums over each patch's points, in the points' order
    """
    f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)  # noqa: E731
    return _patch_normal_equations(f64(p), f64(r), f64(M), f64(W), f64(tangential),
                                   np.ascontiguousarray(labels, dtype=np.int64), int(count))


__all__ = ["closest_among_faces", "colour_choice", "patch_normal_equations", "rotation_fit_compiled"]
