"""Coupled per-patch rigid steps (engine.align.rigid.coupled_patch_steps)."""

import numpy as np

from engine.align.rigid import coupled_patch_steps, patch_rigid_steps


def _patches(seed=0, count=4, per=60):
    """Points of ``count`` patches in a row along x, with normals, labels and a known rigid motion."""
    rng = np.random.default_rng(seed)
    P = np.concatenate([rng.normal(size=(per, 3)) * 0.05 + [0.2 * k, 0, 0] for k in range(count)])
    M = rng.normal(size=P.shape)
    M /= np.linalg.norm(M, axis=1, keepdims=True)
    labels = np.repeat(np.arange(count), per)
    return P, M, labels


def _coupling(count, weight, spacing=0.2):
    pairs = np.array([[k, k + 1] for k in range(count - 1)])
    points = np.array([[spacing * (k + 0.5), 0.0, 0.0] for k in range(count - 1)])
    return pairs, points, np.full(len(pairs), 0.03), weight


def test_no_coupling_gives_the_independent_steps():
    P, M, labels = _patches()
    Y = P + [0.01, 0.0, 0.0]
    W, tau = np.ones(len(P)), np.full(len(P), 0.05)
    free = patch_rigid_steps(P, Y, M, W, tau, labels, 4)
    zero = patch_rigid_steps(P, Y, M, W, tau, labels, 4, coupling=_coupling(4, 0.0))
    for a, b in zip(free, zero):
        assert np.array_equal(a, b)


def test_a_shared_motion_is_not_changed_by_the_coupling():
    # every patch's data ask for the same small rigid motion of the whole: coupled steps agree
    # (linear data, so each patch alone finds it but for the solver's 1e-3 damping)
    P, M, labels = _patches(1)
    P = 4.0 * P  # patches 20 cm wide, so the damping hardly shrinks their rotations
    omega, t = np.array([0.0, 0.01, 0.005]), np.array([0.004, -0.002, 0.003])
    Y = P + np.cross(omega, P) + t
    W, tau = np.ones(len(P)), np.full(len(P), 1.0)
    free = patch_rigid_steps(P, Y, M, W, tau, labels, 4)
    tied = patch_rigid_steps(P, Y, M, W, tau, labels, 4, coupling=_coupling(4, 5.0, 0.8))
    np.testing.assert_allclose(free[0], np.tile(omega, (4, 1)), atol=1e-4)
    np.testing.assert_allclose(tied[0], np.tile(omega, (4, 1)), atol=1e-4)
    np.testing.assert_allclose(free[1], tied[1], atol=2e-5)


def test_a_patch_without_data_follows_its_neighbours():
    P, M, labels = _patches(2, count=3)
    Y = P + [0.0, 0.02, 0.0]
    W, tau = np.ones(len(P)), np.full(len(P), 1.0)
    W[labels == 1] = 0.0  # the middle patch sees nothing
    omega, shift, _ = patch_rigid_steps(P, Y, M, W, tau, labels, 3)
    assert np.abs(shift[1]).max() < 1e-9  # alone it stays where it is
    omega, shift, _ = patch_rigid_steps(P, Y, M, W, tau, labels, 3, coupling=_coupling(3, 0.5))
    np.testing.assert_allclose(shift[1], [0.0, 0.02, 0.0], atol=5e-5)  # tied, it moves with them
    np.testing.assert_allclose(omega[1], 0.0, atol=1e-6)


def test_coupled_steps_solve_the_stated_energy():
    rng = np.random.default_rng(3)
    count = 3
    A = rng.normal(size=(count, 6, 6))
    H = np.einsum("pij,pkj->pik", A, A) + 0.1 * np.eye(6)
    g = rng.normal(size=(count, 6))
    centres = rng.normal(size=(count, 3))
    pairs, points, spread, weight = np.array([[0, 1], [1, 2]]), rng.normal(size=(2, 3)), np.array([0.1, 0.2]), 0.7
    delta = coupled_patch_steps(H, g, centres, pairs, points, spread, weight)

    def energy(d):
        d = d.reshape(count, 6)
        e = sum(0.5 * d[p] @ H[p] @ d[p] + g[p] @ d[p] for p in range(count))
        trans = np.trace(H[:, 3:, 3:], axis1=1, axis2=2)
        for (a, b), q, r in zip(pairs, points, spread):
            k = weight * (trans[a] + trans[b]) / 6.0
            ua = np.cross(d[a, :3], q - centres[a]) + d[a, 3:]
            ub = np.cross(d[b, :3], q - centres[b]) + d[b, 3:]
            e += 0.5 * k * (np.sum((ua - ub) ** 2) + r * r * np.sum((d[a, :3] - d[b, :3]) ** 2))
        return e

    best = energy(delta.ravel())
    for _ in range(20):  # any other step costs more
        assert energy(delta.ravel() + 1e-3 * rng.normal(size=6 * count)) > best
