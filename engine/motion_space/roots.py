"""Root motion of a space's sources against its heading reference (``prepare_sources``' first step)."""

from __future__ import annotations

import numpy as np

from engine.root_motion import estimate_root_motion, travel_turn
from engine.timewarp import detect_events, estimate_period


def cyclic_root(clip, faces, rest):
    """Root motion of a cyclic clip filtered over its period (estimated when not given)."""
    V = np.asarray(clip.vertices, dtype=np.float64)
    period = clip.frames_per_cycle
    if period is None:
        rough = estimate_root_motion(V, faces, clip.fps, smoothing=0.5, reference=rest)
        period = estimate_period(rough.local, clip.fps)
    if period + 1 > len(V):
        raise ValueError(f"{clip.name}: {len(V)} frames do not hold a whole cycle of {period:.1f} frames")
    return estimate_root_motion(V, faces, clip.fps, period=period, reference=rest), float(period)


def source_roots(clips, faces, reference, size, cyclic):
    """Root motion of every clip against the heading ``reference``, and what was found (period, events)."""
    roots, info = [], []
    for clip in clips:
        if cyclic:
            root, period = cyclic_root(clip, faces, reference)
            info.append({"name": clip.name, "period_frames": float(period)})
        else:
            root = estimate_root_motion(np.asarray(clip.vertices, dtype=np.float64), faces, clip.fps,
                                        reference=reference)
            events = detect_events(root.local, model_size=size)
            info.append({"name": clip.name, "events_kind": events.kind, "events_frames": list(events.times)})
        roots.append(root)
    return roots, info


def capture_travel_turn(clips, faces, rest, size):
    """The turn about +Y (radians) from ``rest``'s facing to the way a whole capture travels
    (``travel_turn`` over all its takes), or 0.

    ``clips`` are SourceClips in the rest's vertices: every sequence of an aligned capture, whose
    rest is its root frame. A cyclic take's root motion is filtered over its cycle (a take too
    short to hold one says nothing), a one-shot take's heading goes from its first frames' to
    its last frames'. A straight walk or run travels within ``FORWARD_CONE`` of its facing and
    counts; reaches, jumps on the spot and dances that do not travel forward do not. Spaces built
    from the capture then share this one heading 0, whatever their own sources do (a reach space
    travels nowhere; a gait space built alone would take its own sources' turn).
    """
    roots = []
    for clip in clips:
        if len(clip.vertices) < 2:
            continue
        try:
            roots += source_roots([clip], faces, rest, size, clip.cyclic)[0]
        except ValueError:  # a cyclic take shorter than its cycle
            continue
    return travel_turn(roots, size)


__all__ = ["capture_travel_turn", "cyclic_root", "source_roots"]
