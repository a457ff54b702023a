"""The leg rig's hot path (engine/graph/legs.py, compiled in engine/graph/compiled.py) gives the
same numbers, to rounding, as the plain numpy formulation it replaced (kept here as the
reference: ``reference_reachable``, ``reference_move``, ``two_bone``, ``rotation_between``), over
random holds of the tiny graph's frames: offsets within reach, out of reach, past the cap,
straight legs that stretch; and joints found once and reused give the same plan."""

import math

import numpy as np
import pytest

from engine.graph import MotionGraph
from engine.graph.clock import foot_vertices
from engine.graph.feet import FootPins
from engine.graph.legs import LegRig


def _norm(v):
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def rotation_between(p, q):
    """(3, 3) the smallest rotation turning the direction of ``p`` into that of ``q`` (Rodrigues)."""
    p, q = np.asarray(p, dtype=float) / _norm(p), np.asarray(q, dtype=float) / _norm(q)
    axis = np.cross(p, q)
    s, c = _norm(axis), float(p @ q)
    if s < 1e-12:
        return np.eye(3)
    kx, ky, kz = axis / s
    K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def two_bone(hip, knee, ankle, target, scale=1.0, forward=(0.0, 0.0, 1.0)):
    """The knee's new place for the ankle at ``target``, thigh and shin keeping their lengths
    times ``scale``, the knee bending in the plane it bends in now (``forward`` if straight)."""
    hip, knee, ankle, target = (np.asarray(x, dtype=float) for x in (hip, knee, ankle, target))
    l1, l2 = scale * _norm(knee - hip), scale * _norm(ankle - knee)
    d = _norm(target - hip)
    u = (target - hip) / d
    bend = (knee - hip) - ((knee - hip) @ u) * u
    if _norm(bend) < 1e-6 * l1:
        bend = np.asarray(forward, dtype=float) - (np.asarray(forward, dtype=float) @ u) * u
    v = bend / _norm(bend)
    cos = min(max((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0), 1.0)
    return hip + l1 * (cos * u + math.sqrt(1.0 - cos * cos) * v)


def reference_reachable(rig, k, offset, joints):
    hip, knee, ankle = joints
    size = float(np.linalg.norm(offset))
    if size == 0.0:
        return 1.0
    t = min(1.0, rig.cap * rig.legs[k]["length"] / size)
    reach = (np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee)) * (1.0 + rig.stretch) * (1.0 - 1e-9)
    a = ankle - hip
    if np.linalg.norm(a + t * offset) > reach:
        b, c = float(a @ offset), float(a @ a) - reach * reach
        s = (-b + np.sqrt(max(b * b - size * size * c, 0.0))) / (size * size)
        t = min(t, max(s, 0.0))
    return float(t)


def reference_move(rig, mesh, offsets, shares, joints):
    for leg, offset, t, found in zip(rig.legs, np.asarray(offsets, dtype=np.float64), shares, joints):
        if found is None or t == 0.0:
            continue
        hip, knee, ankle = found
        target = ankle + t * offset
        scale = max(1.0, _norm(target - hip) / (_norm(knee - hip) + _norm(ankle - knee)))
        new_knee = two_bone(hip, knee, ankle, target, scale)
        R1 = rotation_between(knee - hip, new_knee - hip)
        R2 = rotation_between(ankle - knee, target - new_knee)
        A1, A2 = R1.T, R2.T
        if scale > 1.0:
            e1, e2 = (new_knee - hip) / _norm(new_knee - hip), (target - new_knee) / _norm(target - new_knee)
            A1 = A1 @ (np.eye(3) + (scale - 1.0) * np.outer(e1, e1))
            A2 = A2 @ (np.eye(3) + (scale - 1.0) * np.outer(e2, e2))
        b = np.stack([hip - hip @ A1, new_knee - knee @ A2, t * offset])
        x = np.asarray(mesh[leg["index"]], dtype=np.float64)
        w = leg["weights"]
        turned = x @ np.concatenate([A1, A2], axis=1)
        moved = x * leg["kept"] + w[:, :1] * turned[:, :3] + w[:, 1:2] * turned[:, 3:] + w @ b
        mesh[leg["index"]] = moved


@pytest.fixture(scope="module")
def graph(motion_graph_file):
    with MotionGraph.open(motion_graph_file) as g:
        yield g


def random_holds(graph, count, seed):
    """(mesh (n, 3) float32, offsets (legs, 3) root-local horizontal) of random frames of the
    graph's nodes, offsets from nothing to past the cap, some legs without one."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        node = graph.nodes[int(rng.integers(len(graph.nodes)))]
        w = node.samples.weights[int(rng.integers(len(node.samples.weights)))]
        mesh = np.array(node.space.blender("hybrid").blend(w, float(rng.uniform())), dtype=np.float32)
        offsets = np.zeros((2, 3))
        for k in range(2):
            if rng.uniform() < 0.8:
                angle, size = rng.uniform(0, 2 * np.pi), rng.choice([0.01, 0.05, 0.12, 0.3]) * rng.uniform(0.2, 1.0)
                offsets[k, [0, 2]] = size * np.cos(angle), size * np.sin(angle)
        yield mesh, offsets


@pytest.mark.parametrize("stretch", [0.03, 0.0])
def test_the_rig_moves_the_legs_as_the_plain_numpy_formulation(graph, stretch):
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    rig = LegRig(rest, foot_vertices(rest), stretch=stretch)
    stretched = shortened = 0
    for mesh, offsets in random_holds(graph, 200, seed=int(stretch * 100)):
        shares, joints = rig.reach(mesh, offsets)
        expected = [reference_reachable(rig, k, o, j) if j is not None else 1.0
                    for k, (o, j) in enumerate(zip(offsets, joints))]
        # to rounding, not bit for bit: numpy's norms and dot products of 3-vectors sum in an order
        # that depends on the CPU's SIMD kernels (a fresh CI host differed in the last bit)
        np.testing.assert_allclose(shares, expected, rtol=1e-12, atol=0)
        moved, reference = mesh.copy(), mesh.copy()
        rig.move(moved, offsets, shares, joints)
        reference_move(rig, reference, offsets, shares, joints)
        np.testing.assert_allclose(moved, reference, rtol=0, atol=1e-6)  # float32 metres: a few ulps
        shortened += int((shares < 1.0).sum())
        for k, j in enumerate(joints):
            if j is not None:
                target = j[2] + shares[k] * offsets[k]
                stretched += _norm(target - j[0]) > _norm(j[1] - j[0]) + _norm(j[2] - j[1])
    assert shortened > 0          # offsets out of reach or past the cap were among them
    if stretch:
        assert stretched > 0      # and legs that had to lengthen


def test_joints_found_once_give_the_same_plan(graph):
    """FootPins.prepare with the joints already found on the mesh (a held frame plans twice)."""
    rest = np.asarray(graph.nodes[0].space.container["rest"])
    feet = foot_vertices(rest)
    ground = float(rest[:, 1].min()) + 0.01
    for mesh, offsets in random_holds(graph, 50, seed=7):
        fresh, cached = FootPins(rest, feet, ground), FootPins(rest, feet, ground)
        fresh.offsets[:] = cached.offsets[:] = offsets[:, [0, 2]]
        known = [None, None]
        cached.prepare(mesh, 0.4, known)
        cached.offsets[:] = offsets[:, [0, 2]]  # the second plan of the frame, joints known
        local, shares, joints = cached.prepare(mesh, 0.4, known)
        local_f, shares_f, joints_f = fresh.prepare(mesh, 0.4)
        assert shares.tolist() == shares_f.tolist() and local.tolist() == local_f.tolist()
        for a, b in zip(joints, joints_f):
            assert (a is None) == (b is None) and (a is None or all(np.array_equal(x, y) for x, y in zip(a, b)))
        assert cached.holding() == fresh.holding() == bool(offsets.any())
