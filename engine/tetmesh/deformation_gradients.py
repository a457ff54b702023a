"""Per-tetrahedron deformation gradients."""

from __future__ import annotations

from ._validate import as_tets, as_vertices, edge_matrices, inverse_edge_matrices


def rest_inverse(V_rest, T):
    """The (t, 3, 3) inverses of the rest edge matrices that :func:`deformation_gradients` needs,
    for a caller that asks about many deformed poses of one rest pose (a ``ValueError`` names
    degenerate tets)."""
    return inverse_edge_matrices(as_vertices(V_rest, "V_rest"), as_tets(T, len(V_rest)), "V_rest")


def deformation_gradients(V_rest, V_def, T, *, rest_inverse=None):
    """Affine deformation gradient of every tetrahedron from a rest to a deformed pose.

    Parameters
    ----------
    V_rest : (k, 3) float array   rest tet-mesh vertex positions (no degenerate tets)
    V_def : (k, 3) float array    deformed positions of the same vertices
    T : (t, 4) int array          tetrahedra
    rest_inverse : (t, 3, 3) float array, optional
                                  :func:`rest_inverse` of ``V_rest`` and ``T``, computed once
                                  (the same result, without inverting the rest edges again)

    Returns
    -------
    F : (t, 3, 3) float64 array
        ``F[i] @ (x_j - x_0) == y_j - x_0'`` for the edges of tet ``i`` (rest ``x``, deformed
        ``y``); translation-free. ``F[i].T`` is the (3, 3) block ``tet_gradient(V_rest, T) @
        V_def`` at rows ``3*i .. 3*i + 2``.

    Notes
    -----
    ``F = E_def E_rest^{-1}`` with ``E`` the edge matrices; the per-element quantity that the
    non-linear blend of Casas et al. 2012, section 4.1, splits into rotation and stretch
    (:func:`polar_decomposition`).
    """
    V_rest = as_vertices(V_rest, "V_rest")
    V_def = as_vertices(V_def, "V_def")
    if V_def.shape != V_rest.shape:
        raise ValueError(f"V_def has shape {V_def.shape}, V_rest has {V_rest.shape}")
    T = as_tets(T, len(V_rest))
    if rest_inverse is None:
        rest_inverse = inverse_edge_matrices(V_rest, T, "V_rest")
    elif rest_inverse.shape != (len(T), 3, 3):
        raise ValueError(f"rest_inverse has shape {rest_inverse.shape}, expected ({len(T)}, 3, 3)")
    return edge_matrices(V_def, T) @ rest_inverse
