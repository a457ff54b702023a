"""The synthetic studio: BVH, retargeting, the dressed MakeHuman body, per-frame reconstruction."""

import numpy as np
import pytest
import trimesh

from engine.surface import SurfaceQuery, enclosed_volume
from engine.synthetic import get_preset
from engine.synthetic.studio import (
    STUDIO_TINY,
    BvhError,
    StudioCamera,
    StudioSequenceSpec,
    build_studio_body,
    forward_kinematics,
    generate_studio_sequence,
    parse_bvh,
    retarget,
    to_file,
    to_metres_y_up,
    truth_to_file,
)
from engine.synthetic.studio.assets import TAKES, makehuman_body, mocap_take
from engine.synthetic.studio.reconstruct import frame_statistics
from engine.synthetic.studio.retarget import t_pose
from engine.synthetic.studio.sequences import animate_studio, studio_motion
from engine.synthetic.studio.voxelize import grid_for, occupancy

TWO_JOINTS = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Arm
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0 100 0 0 0 0 0 0 0
1 2 3 90 0 0 0 0 90
"""


@pytest.fixture(scope="module")
def tiny_body():
    return build_studio_body(STUDIO_TINY.body_vertices, STUDIO_TINY.garment_detail)


def test_bvh_forward_kinematics_is_exact_on_a_two_joint_chain():
    bvh = parse_bvh(TWO_JOINTS)
    assert bvh.names == ("Hips", "Arm") and bvh.fps == 2.0 and bvh.frames == 2
    R, P = forward_kinematics(bvh)
    np.testing.assert_allclose(P[0], [[0, 100, 0], [10, 100, 0]], atol=1e-12)
    # Frame 1: the root turns 90 degrees about Z, so the arm's offset (10, 0, 0) points along +Y;
    # the arm's own 90 degrees about X composes after its parent's (intrinsic Z Y X order).
    np.testing.assert_allclose(P[1], [[1, 2, 3], [1, 12, 3]], atol=1e-12)
    np.testing.assert_allclose(R[1, 1] @ [0, 1, 0], [0, 0, 1], atol=1e-12)


def test_bvh_errors_name_the_source_and_line():
    with pytest.raises(BvhError, match=r"take\.bvh: line 5: bad channel list"):
        parse_bvh(TWO_JOINTS.replace("CHANNELS 6 Xposition", "CHANNELS 6 Wposition"), source="take.bvh")
    with pytest.raises(BvhError, match="2 frames announced, 1 present"):
        parse_bvh(TWO_JOINTS.rsplit("\n", 2)[0] + "\n", source="take.bvh")


def test_cmu_takes_put_the_head_near_165_cm():
    bvh = mocap_take("002_01")
    assert bvh.frames == 171 and bvh.fps == pytest.approx(60.0, rel=1e-4)
    _, P = forward_kinematics(bvh)
    head, foot = P[:, bvh.index("CC_Base_Head"), 1], P[:, bvh.index("CC_Base_L_Foot"), 1]
    assert np.median(head) == pytest.approx(165.0, abs=3.0)  # centimetres, Y up
    assert 5.0 < np.median(foot) < 20.0
    assert set(TAKES) >= {"002_05", "005_02", "005_06", "005_17"}


def test_the_makehuman_template_is_closed_and_dressed():
    data = makehuman_body()
    assert data["vertices"].dtype == np.float32 and data["faces"].dtype == np.int32
    body = build_studio_body()
    assert np.sum(body.part == 0) == 13_380
    for name in ("body", "skirt", "sleeve_l", "sleeve_r"):
        mesh = trimesh.Trimesh(body.V, body.part_faces(name), process=False)
        mesh.remove_unreferenced_vertices()
        assert mesh.is_watertight and mesh.is_winding_consistent, name
        assert mesh.euler_number == (2 if name == "body" else 0), name  # a sphere; shells are tori
        assert enclosed_volume(mesh.vertices, mesh.faces) > 0, name  # outward oriented
    assert body.V[:, 1].min() == pytest.approx(0.0, abs=1e-6)  # feet on the ground
    assert 1.6 < body.V[:, 1].max() < 1.75 and body.V[:, 2].max() > 0.15  # about 1.67 m, facing +Z
    np.testing.assert_allclose(body.weight.sum(axis=1), 1.0, atol=1e-5)


def test_t_pose_raises_the_arms_to_the_horizontal(tiny_body):
    sk = tiny_body.skeleton
    S = t_pose(sk)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        for bone in ("upperarm", "lowerarm"):
            j = sk.index(f"{bone}_{side}")
            direction = S[j] @ (sk.tails[j] - sk.rest[j])
            np.testing.assert_allclose(direction / np.linalg.norm(direction), [sign, 0, 0], atol=1e-9)
    np.testing.assert_allclose(S[sk.index("spine_03")], np.eye(3))


def test_retargeted_walk_keeps_the_body_and_walks_forward(tiny_body):
    sk = tiny_body.skeleton
    motion = retarget(sk, "002_01", fps=25.0)
    assert motion.frames == 71  # 170 intervals at 60 fps = 2.83 s
    # Bone lengths are the body's own in every frame.
    thigh, calf = sk.index("thigh_l"), sk.index("calf_l")
    length = np.linalg.norm(motion.positions[:, calf] - motion.positions[:, thigh], axis=1)
    np.testing.assert_allclose(length, np.linalg.norm(sk.rest[calf] - sk.rest[thigh]), rtol=1e-9)
    V, positions = animate_studio(tiny_body, motion)
    on_body = tiny_body.part == 0
    height = V[:, on_body, 1].max(axis=1)
    assert np.all(np.abs(height - tiny_body.V[:, 1].max()) < 0.06)  # upright, the body's own height
    assert np.all(V[:, on_body, 1].min(axis=1) > -1e-9) and np.median(V[:, on_body, 1].min(axis=1)) < 0.02
    travel = positions[-1, 0] - positions[0, 0]
    assert 2.5 < travel[2] < 4.5 and abs(travel[0]) < 0.5  # starts facing +Z, ~1.2 m/s
    R = motion.rotations
    np.testing.assert_allclose(np.einsum("fjab,fjcb->fjac", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    # The legs push the skirt aside: no skirt point is inside a leg capsule.
    skirt = V[:, tiny_body.part == 1]
    for head, tail, r0, r1 in tiny_body.capsules:
        A, B = positions[:, head][:, None], positions[:, tail][:, None]
        t = np.clip(np.sum((skirt - A) * (B - A), -1) / np.sum((B - A) ** 2, -1), 0, 1)
        d = np.linalg.norm(skirt - (A + t[..., None] * (B - A)), axis=-1)
        assert np.all(d >= r0 + t * (r1 - r0) - 1e-9)


def test_occupancy_of_the_template_has_its_volume(tiny_body):
    h = 0.008
    origin, shape = grid_for(tiny_body.V, h, 2)
    faces = tiny_body.part_faces("body")
    inside = occupancy(tiny_body.V, faces, origin, h, shape)
    assert inside.sum() * h**3 == pytest.approx(enclosed_volume(tiny_body.V, faces), rel=0.01)
    # Two interpenetrating copies occupy their union, not their symmetric difference.
    shifted = tiny_body.V + np.array([0.05, 0.0, 0.0])
    both = occupancy(np.concatenate([tiny_body.V, shifted]), np.concatenate([faces, faces + len(tiny_body.V)]),
                     origin, h, (shape[0] + 8, shape[1], shape[2]))
    assert both.sum() > inside.sum()


@pytest.fixture(scope="module")
def strikes(tiny_body):
    spec = StudioSequenceSpec("strikes", "performance", takes=(("002_05", 2.0, 2.4),), units="mm", up="+Z")
    return generate_studio_sequence(tiny_body, spec, fps=12.5, camera=STUDIO_TINY.camera, seed=3)


def test_reconstructed_frames_have_holes_fragments_and_noise(tiny_body, strikes):
    camera = STUDIO_TINY.camera
    meta = strikes["meta"]
    assert meta["frames"] == 6 and len(strikes["unstructured"]) == 6
    components = []
    for k, (V, F, C) in enumerate(strikes["unstructured"]):
        stats = frame_statistics(F, len(V))
        assert stats["boundary_edges"] > 0 and stats["holes"] >= 1  # open, and differently so per frame
        components.append(stats["components"])
        assert abs(len(V) - camera.vertices) < 0.35 * camera.vertices
        assert C.shape == V.shape and 0 <= C.min() and C.max() <= 1
        distance = SurfaceQuery(strikes["vertices"][k], tiny_body.F).closest(V)[3]
        # Noise along the normals: |N(0, 2.5 mm)| has median 1.7 mm (plus grid and decimation error).
        assert 0.001 < np.median(distance) < 0.004
    assert max(components) >= 2  # floating fragments besides the body
    assert np.mean(components) - 1 >= 0.5 * meta["studio"]["fragments_per_frame"]
    counts = [len(V) for V, _, _ in strikes["unstructured"]]
    assert len(set(counts)) > 1  # every frame is meshed on its own
    assert meta["studio"]["fragments_per_frame"] > 0 and meta["studio"]["holes_per_frame"] >= 1


def test_truth_is_consistent_and_recorded_in_the_files_units(strikes):
    meta, truth = strikes["meta"], strikes["truth"]
    assert (meta["units"], meta["up"], meta["forward"]) == ("mm", "+Z", "-Y")
    M = np.array(meta["from_metres_y_up"])
    assert np.linalg.det(M) == pytest.approx(1e9)  # 1000^3 times a proper rotation: windings kept
    np.testing.assert_allclose(M @ [0, 1, 0], [0, 0, 1000])  # +Y up becomes +Z up
    np.testing.assert_allclose(truth["template_positions"], strikes["vertices"], atol=1e-6)
    in_file = truth_to_file(truth, "mm", "+Z")
    np.testing.assert_allclose(in_file["template_positions"], to_file(strikes["vertices"], "mm", "+Z"), rtol=1e-6)
    np.testing.assert_allclose(to_metres_y_up(in_file["joint_positions"], "mm", "+Z"), truth["joint_positions"],
                               atol=1e-9)
    assert in_file["template_positions"][..., 2].max() > 1500  # millimetres, Z up: the head is high in z


def test_presets_are_registered_and_the_tiny_one_is_small():
    studio = get_preset("studio")
    long = [s for s in studio.sequences if s.kind == "performance"]
    assert {s.name for s in long} == {"strikes", "dance"} and studio.fps == 25.0
    assert {(s.units, s.up) for s in studio.sequences} >= {("m", "+Y"), ("mm", "+Y"), ("mm", "+Z"), ("m", "+Z")}
    assert studio.vertices == 10_000 and 2.0 <= studio.noise_mm <= 3.0
    tiny = get_preset("studio-tiny")
    assert len(tiny.sequences) == 3 and tiny.camera.vertices < 5000


def test_contact_poses_merge_limbs(tiny_body):
    spec = get_preset("studio").sequences[8]
    assert spec.name == "contacts"
    motion = studio_motion(tiny_body.skeleton, spec, fps=5.0)
    V, _ = animate_studio(tiny_body, motion)
    from engine.synthetic.studio.reconstruct import contact_vertices

    hands = np.concatenate([tiny_body.hand_vertices("l"), tiny_body.hand_vertices("r")])
    standing = contact_vertices(tiny_body.V, V[0])[hands].sum()
    on_hips = contact_vertices(tiny_body.V, V[6])[hands].sum()  # t = 1.2 s: hands on hips
    assert on_hips > 10 and on_hips > 3 * standing
    camera = StudioCamera(spacing=0.012, merge=0.026, vertices=2500)
    from engine.synthetic.studio.sequences import head_marks, reconstruct_frames

    truth = {"joint_rotations": motion.rotations, "joint_positions": motion.positions}
    _, stats = reconstruct_frames(tiny_body, V, head_marks(tiny_body, truth), camera, seed=0, frames=[6])
    assert stats[0]["merged"] > 0


def test_a_frame_is_reconstructed_the_same_way_twice_and_differently_with_another_seed(tiny_body, strikes):
    from engine.synthetic.studio.sequences import head_marks, reconstruct_frames

    heads = head_marks(tiny_body, strikes["truth"])
    camera = STUDIO_TINY.camera
    (a,), _ = reconstruct_frames(tiny_body, strikes["vertices"], heads, camera, seed=3, frames=[2])
    (b,), _ = reconstruct_frames(tiny_body, strikes["vertices"], heads, camera, seed=3, frames=[2])
    (c,), _ = reconstruct_frames(tiny_body, strikes["vertices"], heads, camera, seed=4, frames=[2])
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a[0], strikes["unstructured"][2][0])  # as generate_studio_sequence made it
    assert len(c[0]) != len(a[0]) or not np.array_equal(c[0], a[0])


def test_a_take_of_several_clips_at_a_low_frame_rate(tiny_body):
    """The dance joins three clips with a 0.4 s cross-fade: at 2 fps that is one frame, and the
    facing of the frame it starts from was read from an empty slice (``--fps 1.79`` crashed)."""
    spec = next(s for s in get_preset("studio").sequences if s.name == "dance")
    slow, usual = (studio_motion(tiny_body.skeleton, spec, fps=fps) for fps in (2.0, 25.0))
    assert len(slow.rotations) == pytest.approx(len(usual.rotations) * 2.0 / 25.0, abs=3)
    assert np.isfinite(slow.positions).all()


def test_the_studio_lights_shade_the_albedo_and_every_frame_exposes_differently(tiny_body, strikes):
    from dataclasses import replace

    from engine.synthetic.studio.lighting import StudioLight, lit_colours
    from engine.synthetic.studio.sequences import head_marks, reconstruct_frames

    light = StudioLight()
    key = np.asarray(light.key[0]) / np.linalg.norm(light.key[0])
    shading = light.shading(np.stack([key, -key]))
    assert shading[0] > 1.2 and shading[1] < 0.95       # facing the key light, and turned away
    directions = np.random.default_rng(0).normal(size=(200_000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert light.shading(directions).mean() == pytest.approx(1.0, abs=0.005)   # the albedo on average
    grey = np.full((4, 3), 0.5)
    normals = np.tile([0.0, 1.0, 0.0], (4, 1))
    first, again = (lit_colours(grey, normals, np.random.default_rng(1), light) for _ in range(2))
    np.testing.assert_array_equal(first, again)
    other = lit_colours(grey, normals, np.random.default_rng(2), light)
    assert np.abs(first.mean(axis=0) - other.mean(axis=0)).max() > 1e-3   # another frame, another exposure
    # the same frame reconstructed with and without the light: the same geometry, colours shaded
    heads = head_marks(tiny_body, strikes["truth"])
    camera = STUDIO_TINY.camera
    (lit,), _ = reconstruct_frames(tiny_body, strikes["vertices"], heads, camera, seed=3, frames=[2])
    (bare,), _ = reconstruct_frames(tiny_body, strikes["vertices"], heads, replace(camera, light=None), seed=3,
                                    frames=[2])
    np.testing.assert_array_equal(lit[0], bare[0])
    np.testing.assert_array_equal(lit[1], bare[1])
    ratio = (lit[2].sum(axis=1) + 1e-3) / (bare[2].sum(axis=1) + 1e-3)
    assert np.percentile(ratio, 95) - np.percentile(ratio, 5) > 0.15
