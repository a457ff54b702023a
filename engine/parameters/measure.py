"""Motion parameters measured on a blend itself (``measure_parameters``), and how well a space's
parameter map realises requested parameters (``accuracy_report``)."""

from __future__ import annotations

import numpy as np

from engine import measures
from engine.parameters.layout import MEASURES


def measure_parameters(names, w, track, blend_phases, *, faces=None, effector=None):
    """Parameters of the blend with weights ``w``, measured on the blended motion itself.

    Parameters
    ----------
    names : sequence of str          among MEASURES
    w : (N,) float array
    track : RootTrack
    blend_phases : callable(w) -> (P, n, 3)   the blended root-local frames on the phase grid
    faces : (m, 3) int array         for the centre of mass (jump height)
    effector : (h,) int array        hand vertices (reach height)

    Returns
    -------
    (len(names),) float array in MEASURES units

    Notes
    -----
    Speed and turn rate: the root's path length and heading change per cycle over the blended
    duration; jump distance: the horizontal root displacement over the clip; jump height: the
    centre of mass's peak rise (vertical motion stays in the meshes); reach height: the
    effector's height at its farthest from its start (``engine.measures``).
    """
    out = []
    frames = None
    T = track.duration(w)
    for name in names:
        if name in ("speed", "turn_rate", "jump_distance"):
            step, turn = track.rates(w)
            if name == "speed":
                out.append(float(np.linalg.norm(step.mean(axis=0)[[0, 2]]) / T))
            elif name == "turn_rate":
                out.append(float(np.degrees(turn.mean() / T)))
            else:
                position, _ = track.integrate(w)
                out.append(float(np.linalg.norm(position[-1, [0, 2]] - position[0, [0, 2]])))
        elif name in ("jump_height", "reach_height"):
            if frames is None:
                frames = np.asarray(blend_phases(w), dtype=np.float64)
            if name == "jump_height":
                out.append(measures.jump_height(measures.centre_of_mass(frames, faces)))
            else:
                out.append(measures.reach_height(frames, effector))
        else:
            raise ValueError(f"unknown parameter measure {name!r}; choose one of {', '.join(MEASURES)}")
    return np.array(out)


def accuracy_report(space, blend_mode="hybrid", per_axis=None):
    """Realised vs requested parameters over the reachable domain of a space's parameter map.

    Requests on a regular grid of each parameter's domain (per_axis values per axis, default
    41 for one parameter, 9 x 9 for two) that the map says are reachable are solved for blend
    weights; the parameters are then measured again on the blend itself (``measure_parameters``
    on ``blend_mode`` blends), not read back from the map.

    Returns
    -------
    dict with, per parameter, max and mean |realised - requested| in units and in % of the
    parameter's range, the number of requests and how many were unreachable.
    """
    from engine.blend.phase import phase_of_sample

    pmap = space.parameter_map
    if pmap is None:
        raise ValueError(f"{space.name}: the space has no parameter map")
    blender = space.blender(blend_mode)
    P = space.n_phases

    def blend_phases(w):
        return np.stack([blender.blend(w, phase_of_sample(p, P, space.cyclic)) for p in range(P)])

    faces = np.asarray(space.faces, dtype=np.int64)
    per_axis = per_axis or (41 if len(pmap.names) == 1 else 9)
    axes = [np.linspace(lo, hi, per_axis) for lo, hi in pmap.domain()]
    requests = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
    errors, unreachable = [], 0
    for p in requests:
        solution = pmap.solve(p)
        if solution.clamped:
            unreachable += 1
            continue
        realised = measure_parameters(pmap.names, solution.weights, space.root_track, blend_phases, faces=faces,
                                      effector=space.effector)
        errors.append(np.abs(realised - p))
    errors = np.array(errors).reshape(-1, len(pmap.names))
    result = {"space": space.name, "blend_mode": blend_mode, "requests": int(len(requests)),
              "unreachable": unreachable, "parameters": {}}
    for k, (name, unit) in enumerate(zip(pmap.names, pmap.units)):
        lo, hi = pmap.domain()[k]
        span = max(hi - lo, 1e-12)
        result["parameters"][name] = {
            "unit": unit, "domain": [lo, hi],
            "max_error": float(errors[:, k].max()) if len(errors) else None,
            "mean_error": float(errors[:, k].mean()) if len(errors) else None,
            "max_error_percent_of_range": float(100 * errors[:, k].max() / span) if len(errors) else None,
            "mean_error_percent_of_range": float(100 * errors[:, k].mean() / span) if len(errors) else None}
    return result
