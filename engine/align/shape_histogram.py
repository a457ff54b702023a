"""Volumetric shape histograms of closed meshes (Huang et al. IJCV 2010, the paper's ref [31]).

``H = shape_histogram(V, F, radius=1.2)`` bins the volume enclosed by a frame's surface into
radial shells x elevation bands x azimuthal sectors about the volume centroid, the azimuth
measured about the vertical (+Y) axis. A rotation about the vertical axis only shifts the
sectors circularly; :func:`histogram_distance` factors it out by taking the best circular shift.

The volume is integrated exactly from the surface, without voxels: every (sub-divided) triangle
forms a signed cone with the centroid whose volume ``omega * r^3 / 3`` (solid angle ``omega``,
effective radius ``r``) is spread over the shells below ``r``. Rays through a solid enter and
leave it through triangles of opposite orientation, so the cones of a non-star-shaped body
cancel to the shells it really occupies. Open surfaces (holes) have no inside: for them
:func:`shape_histogram` falls back to the surface area, binned the same way.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from engine.surface import volume_centroid


def is_closed(F):
    """True when every undirected edge of ``F`` is shared by exactly two triangles.

    Parameters
    ----------
    F : (m, 3) int array

    Returns
    -------
    closed : bool
    """
    F = np.asarray(F, dtype=np.int64)
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    code = edges[:, 0] * (int(F.max()) + 1) + edges[:, 1]
    _, counts = np.unique(code, return_counts=True)
    return bool(np.all(counts == 2))


def shape_centre(V, F, *, closed=None):
    """Volume centroid of a closed surface, area centroid of an open one.

    Parameters
    ----------
    V : (n, 3) float array
    F : (m, 3) int array
    closed : bool or None   skip the check when known

    Returns
    -------
    c : (3,) float array
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if closed is None:
        closed = is_closed(F)
    if closed:
        c = volume_centroid(V, F)
        if np.all(np.isfinite(c)):
            return c
    area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    # numpy's sum, not a BLAS product, whose partial sums over 100k+ faces follow its thread count
    return np.sum(area[:, None] * V[F].mean(axis=1), axis=0) / max(area.sum(), 1e-300)


def _subdivide_triangles(A, B, C, levels):
    """Split triangles (q, 3) corner arrays into 4**levels smaller ones each (midpoints)."""
    for _ in range(levels):
        ab, bc, ca = 0.5 * (A + B), 0.5 * (B + C), 0.5 * (C + A)
        A, B, C = (np.concatenate([A, ab, ca, ab]), np.concatenate([ab, B, bc, bc]),
                   np.concatenate([ca, bc, C, ca]))
    return A, B, C


def shape_histogram(V, F, *, radius, shells=10, elevations=8, harmonics=12, centre=None,
                    subdivisions=1, mode="auto"):
    """Volumetric shape histogram of one frame, azimuth in Fourier form.

    Parameters
    ----------
    V : (n, 3) float array   vertices (metres, +Y up)
    F : (m, 3) int array     triangles, outward oriented
    radius : float           outer radius of the last shell; use the same value for every
                             frame that will be compared (volume beyond it counts in the last shell)
    shells, elevations : int
        Uniform radial shells on [0, radius]; elevation bands uniform in the sine of the
        elevation (equal areas on the sphere). Mass is shared linearly between neighbouring
        bands, and the cone of each triangle is split exactly between the shells it spans.
    harmonics : int          azimuthal Fourier coefficients 1..harmonics are kept (the
                             resolution of a histogram with ``2 * harmonics`` sectors)
    centre : (3,) float array or None   default: the volume centroid (area centroid if open)
    subdivisions : int       midpoint subdivisions of every triangle before binning (each one
                             quarters the triangles and sharpens the angular binning)
    mode : {"auto", "volume", "surface"}
        "volume" bins the enclosed volume (needs a closed surface), "surface" the area;
        "auto" picks "volume" for closed surfaces.

    Returns
    -------
    H : (shells, elevations, harmonics + 1) complex array
        ``H[s, e, k]`` = sum over the mass m in cell (s, e) at azimuth phi of m exp(-i k phi),
        normalised so that the total mass ``H[..., 0].sum()`` is 1. The azimuth phi is measured
        about +Y from +Z towards +X. :func:`histogram_sectors` turns it into ordinary sectors.

    Notes
    -----
    Huang, Hilton, Starck, "Shape similarity for 3D video sequences of people", IJCV 2010;
    Casas et al. 2012, section 3.1. Keeping the azimuth as Fourier coefficients (the FFT of a
    finely sectored histogram, computed in closed form) makes a rotation by any angle theta
    about the vertical axis an exact phase factor ``exp(-i k theta)``: ``abs(H)`` is unchanged
    and :func:`histogram_distance` finds the best rotation continuously, not in whole sectors.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        raise ValueError(f"expected V (n, 3) and non-empty F (m, 3), got {V.shape} and {F.shape}")
    if not radius > 0:
        raise ValueError(f"radius must be > 0, got {radius}")
    if min(shells, elevations) < 1 or harmonics < 0:
        raise ValueError("shells and elevations must be >= 1 and harmonics >= 0")
    if mode not in ("auto", "volume", "surface"):
        raise ValueError(f"mode must be auto, volume or surface, got {mode!r}")
    closed = is_closed(F)
    if mode == "volume" and not closed:
        raise ValueError("mode='volume' needs a closed surface (this one has boundary edges)")
    volume = closed if mode == "auto" else mode == "volume"
    c = shape_centre(V, F, closed=closed) if centre is None else np.asarray(centre, dtype=np.float64)
    A, B, C = _subdivide_triangles(V[F[:, 0]] - c, V[F[:, 1]] - c, V[F[:, 2]] - c, int(subdivisions))
    direction = A + B + C
    edges = np.linspace(0.0, radius, shells + 1)
    if volume:
        # Signed solid angle of each triangle seen from the centre (Van Oosterom & Strackee 1983)
        # and the radius r of the spherical cone with the same signed volume omega r^3 / 3.
        la, lb, lc = (np.sqrt(np.einsum("ij,ij->i", X, X)) for X in (A, B, C))
        triple = np.einsum("ij,ij->i", A, np.cross(B, C))
        denominator = (la * lb * lc + np.einsum("ij,ij->i", A, B) * lc
                       + np.einsum("ij,ij->i", A, C) * lb + np.einsum("ij,ij->i", B, C) * la)
        omega = 2.0 * np.arctan2(triple, denominator)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.cbrt(np.where(omega != 0, triple / (2.0 * omega), 0.0))
        # The cone's volume in shell s is omega/3 (min(r, e_s+1)^3 - min(r, e_s)^3): the whole
        # shell for every shell below the one containing r ("top"), the remainder in "top" (the
        # last shell takes everything beyond the radius).
        top = np.clip((r * (shells / radius)).astype(np.int64), 0, shells - 1)
        partial = omega * (r ** 3 - edges[top] ** 3) / 3.0
        whole = omega
    else:
        r = np.sqrt(np.einsum("ij,ij->i", direction, direction)) / 3.0
        top = np.minimum((r * (shells / radius)).astype(np.int64), shells - 1)
        partial = 0.5 * np.linalg.norm(np.cross(B - A, C - A), axis=1)
        whole = None
    # Angular position of each triangle seen from the centre: elevation band (shared linearly
    # between the two nearest band centres) and azimuth phase exp(-i phi), phi = atan2(x, z).
    length = np.maximum(np.sqrt(np.einsum("ij,ij->i", direction, direction)), 1e-300)
    sine = np.clip(direction[:, 1] / length, -1.0, 1.0)
    band_position = (sine + 1.0) * 0.5 * elevations - 0.5  # band centres at integer positions
    band_low = np.floor(band_position)
    band_fraction = band_position - band_low
    band0 = np.clip(band_low.astype(np.int64), 0, elevations - 1)
    band1 = np.clip(band_low.astype(np.int64) + 1, 0, elevations - 1)
    horizontal = np.hypot(direction[:, 0], direction[:, 2])
    unit = np.where(horizontal > 0, (direction[:, 2] - 1j * direction[:, 0]) / np.maximum(horizontal, 1e-300), 1.0)
    n = len(r)
    phase = np.empty((n, harmonics + 1), dtype=np.complex128)
    phase[:, 0] = 1.0
    for k in range(1, harmonics + 1):  # unit ** k, column by column (cheaper than a cumprod)
        np.multiply(phase[:, k - 1], unit, out=phase[:, k])
    cells = shells * elevations
    row0, row1 = top * elevations + band0, top * elevations + band1
    # One sparse (cells x triangles) spread per mass, 2 entries per column (the two bands); both
    # masses stacked into one CSC matrix (no index sorting needed), one product with the phases.
    masses = [partial, whole] if volume else [partial]
    data = np.stack([x for m in masses for x in (m * (1.0 - band_fraction), m * band_fraction)], axis=1)
    index = np.stack([x for j in range(len(masses)) for x in (row0 + j * cells, row1 + j * cells)], axis=1)
    per = 2 * len(masses)
    spread = sp.csc_matrix((data.ravel(), index.ravel(), np.arange(0, per * n + 1, per)),
                           shape=(len(masses) * cells, n))
    binned = np.asarray(spread @ phase).reshape(len(masses), shells, elevations, harmonics + 1)
    H = binned[0]
    if volume:
        # omega per (top shell, band); shell s gets the whole-shell volume of every cone whose
        # top shell lies above s.
        by_top = binned[1]
        above = np.cumsum(by_top[::-1], axis=0)[::-1]  # tops >= s
        above = np.concatenate([above[1:], np.zeros_like(above[:1])])  # tops > s
        H = H + above * (np.diff(edges ** 3) / 3.0)[:, None, None]
    total = H[..., 0].real.sum()
    if not total > 0:
        raise ValueError("the surface encloses no volume (is it inside out?)" if volume
                         else "the surface has no area")
    return H / total


def histogram_sectors(H, azimuths):
    """Ordinary sector histogram from the Fourier form (band-limited; for display and tests).

    Parameters
    ----------
    H : (..., harmonics + 1) complex array   from :func:`shape_histogram`
    azimuths : int                           sectors, >= 2 * harmonics + 1 for no aliasing

    Returns
    -------
    S : (..., azimuths) float array   the mass density sampled at sector centres times the
                                      sector width (sums to the cell masses)
    """
    H = np.asarray(H)
    K = H.shape[-1] - 1
    if azimuths < 2 * K + 1:
        raise ValueError(f"azimuths must be >= {2 * K + 1} for {K} harmonics")
    # density f(phi) = (1/2pi) sum_k H_k e^{ik phi}, sector centres phi_a = 2pi (a + 1/2) / azimuths
    centres = 2.0 * np.pi * (np.arange(azimuths) + 0.5) / azimuths
    k = np.arange(K + 1)
    basis = np.exp(1j * k[:, None] * centres[None, :])  # (K+1, azimuths)
    weight = np.where(k == 0, 1.0, 2.0)[:, None]
    return np.real(np.tensordot(H, weight * basis, axes=([-1], [0]))) / azimuths


def rotation_correlation(H1, H2, steps):
    """Inner products <H1, H2 rotated by theta> at theta = 360 j / steps degrees, j < steps.

    Parameters
    ----------
    H1 : (..., cells..., harmonics + 1) complex array; leading axes broadcast against H2's
    H2 : same trailing shape
    steps : int   rotation samples over the full turn

    Returns
    -------
    c : (..., steps) float array

    Notes
    -----
    With ``f_1, f_2`` the azimuthal densities per cell, ``c(theta) = 2 pi sum_cells
    int f_1(phi) f_2(phi - theta) dphi`` (the rotation that maps frame 2 onto frame 1 is
    +theta about +Y); ``c(0)`` of a histogram with itself is its squared norm.
    """
    cross = np.sum(H1 * np.conj(H2), axis=tuple(range(-3, -1)))
    return correlation_over_rotations(cross, steps)


def correlation_over_rotations(cross, steps):
    """Sum over k in -K..K of cross_k exp(i k theta_j), from the k >= 0 half (Hermitian)."""
    K = cross.shape[-1] - 1
    if steps < 2 * K + 1:
        raise ValueError(f"steps must be >= {2 * K + 1} for {K} harmonics")
    # irfft's normalisation 1/n and Hermitian symmetry give sum_{k=-K..K} X_k e^{ik theta} / n.
    return np.fft.irfft(cross, n=steps, axis=-1) * steps


def histogram_norm2(H):
    """Squared L2 norm of histograms (Parseval over the azimuth), shape (...)."""
    H = np.asarray(H)
    power = np.abs(H) ** 2
    return power[..., 0].sum(axis=(-1, -2)) + 2.0 * power[..., 1:].sum(axis=(-1, -2, -3))


def refine_rotation(cross, degrees, *, iterations=3, max_step=None):
    """Newton steps on the exact correlation from a sampled best rotation.

    Parameters
    ----------
    cross : (..., harmonics + 1) complex array   ``sum_cells H1 conj(H2)`` per harmonic
    degrees : (...) float array                   starting rotations (e.g. from :func:`best_rotation`)
    iterations : int
    max_step : float or None                      largest total change (degrees)

    Returns
    -------
    degrees : (...) float array in (-180, 180]
    peak : (...) float array    the correlation there, ``sum_{k=-K..K} cross_k exp(i k theta)``
    """
    cross = np.asarray(cross)
    k = np.arange(cross.shape[-1], dtype=np.float64)
    start = np.radians(np.asarray(degrees, dtype=np.float64))
    theta = start.copy()
    limit = np.inf if max_step is None else np.radians(max_step)
    for _ in range(iterations):
        z = cross * np.exp(1j * k * theta[..., None])
        slope = -2.0 * np.sum(k * z.imag, axis=-1)
        curvature = -2.0 * np.sum(k * k * z.real, axis=-1)
        step = np.where(curvature < 0, -slope / np.where(curvature < 0, curvature, -1.0), 0.0)
        theta = start + np.clip(theta + step - start, -limit, limit)
    z = cross * np.exp(1j * k * theta[..., None])
    peak = z[..., 0].real + 2.0 * np.sum(z[..., 1:].real, axis=-1)
    degrees = np.degrees(theta)
    degrees = (degrees + 180.0) % 360.0 - 180.0
    degrees = np.where(degrees == -180.0, 180.0, degrees)
    return degrees, peak


def histogram_distance(H1, H2, *, steps=360):
    """L2 distance between two shape histograms at the best rotation about the vertical axis.

    Parameters
    ----------
    H1, H2 : (shells, elevations, harmonics + 1) complex arrays from :func:`shape_histogram`
    steps : int   rotations tried over the full turn (refined by a parabola through the best)

    Returns
    -------
    distance : float   ``min_theta ||f_1 - R_theta f_2||``, the band-limited densities' L2
                       distance (times sqrt(2 pi))
    degrees : float    the rotation about +Y (right-handed, in (-180, 180]) that best maps
                       frame 2 onto frame 1
    """
    H1, H2 = np.asarray(H1), np.asarray(H2)
    if H1.shape != H2.shape or H1.ndim != 3:
        raise ValueError(f"histograms must have equal (shells, elevations, harmonics + 1) shapes, "
                         f"got {H1.shape} and {H2.shape}")
    c = rotation_correlation(H1, H2, steps)
    best, _ = best_rotation(c)
    cross = np.sum(H1 * np.conj(H2), axis=(0, 1))
    best, peak = refine_rotation(cross, best, max_step=360.0 / steps)
    squared = histogram_norm2(H1) + histogram_norm2(H2) - 2.0 * peak
    return float(np.sqrt(max(squared, 0.0))), float(best)


def best_rotation(c):
    """Best rotation from sampled correlations: parabola through the peak and its neighbours.

    Parameters
    ----------
    c : (..., steps) float array   correlations at 360 j / steps degrees

    Returns
    -------
    degrees : (...) float array in (-180, 180]
    peak : (...) float array      the interpolated maximum
    """
    c = np.asarray(c)
    steps = c.shape[-1]
    j = np.argmax(c, axis=-1)
    take = lambda offset: np.take_along_axis(c, ((j + offset) % steps)[..., None], axis=-1)[..., 0]
    left, middle, right = take(-1), take(0), take(1)
    curvature = left - 2.0 * middle + right
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(curvature < 0, 0.5 * (left - right) / curvature, 0.0)
    delta = np.clip(delta, -0.5, 0.5)
    peak = middle - 0.25 * (left - right) * delta
    degrees = (j + delta) * (360.0 / steps)
    degrees = np.where(degrees > 180.0, degrees - 360.0, degrees)
    return degrees, peak


__all__ = ["best_rotation", "correlation_over_rotations", "histogram_distance", "histogram_norm2",
           "histogram_sectors", "is_closed",
           "refine_rotation", "rotation_correlation", "shape_centre", "shape_histogram"]
