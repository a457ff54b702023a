"""A small motion graph straight from the capture generator, for tests and the benchmarks'
``--tiny`` runs: a walk (speed chain, cyclic), a standing idle (no parameters, cyclic) and a
jump (height chain, one-shot) of the 1,000-vertex body at 15 fps, at cheap settings (12 phases,
a coarse hybrid), joined walk <-> stand -> jump -> stand, walk -> jump. About 6 CPU seconds.
``reach=True`` adds a reach (height chain, one-shot) joined stand <-> reach, for the stream's
walk -> jump -> walk -> reach tests."""

from __future__ import annotations

from pathlib import Path

TINY_EDGES = [("walk", "stand"), ("stand", "walk"), ("stand", "jump"), ("jump", "stand"), ("walk", "jump")]
REACH_EDGES = [("stand", "reach"), ("reach", "stand")]


def build_tiny_spaces(directory, *, fps=15.0, reach=False):
    """Write walk.mspace, stand.mspace and jump.mspace (and reach.mspace) into ``directory``."""
    from engine.blend import VolumetricEmbedding
    from engine.motion_space import SourceClip, build_motion_space
    from engine.parameters import Layout
    from engine.synthetic import animate, build_body, gait, jump
    from engine.synthetic import reach as reach_motion
    from engine.synthetic.transitions import stand

    directory = Path(directory)
    body = build_body(1000)
    embedding = VolumetricEmbedding.from_surface(body.V, body.F)
    cheap = dict(epsilon=0.03, rest=body.V, n_phases=12, hybrid_options={"max_depth": 1}, embedding=embedding)
    chain = Layout("chain", 2, chain=(0, 1))
    clips = [SourceClip(f"gait_{v}", animate(body, gait(body.skeleton, v, cycles=2.0, fps=fps)), fps, True)
             for v in (0.9, 1.6)]
    build_motion_space(directory / "walk.mspace", clips, body.F, name="walk",
                       parameters={"layout": chain, "names": ["speed"], "resolution": 5}, **cheap)
    idles = [stand(body.skeleton, breath=0.008, fps=fps, cycles=2),
             stand(body.skeleton, breath=0.006, sway=0.02, period=2.4, fps=fps, cycles=2)]
    clips = [SourceClip(f"stand_{i}", animate(body, m), fps, True) for i, m in enumerate(idles)]
    build_motion_space(directory / "stand.mspace", clips, body.F, name="stand", **cheap)
    clips = [SourceClip(f"jump_{h}", animate(body, jump(body.skeleton, h, 0.6, fps=fps)), fps, False)
             for h in (0.2, 0.45)]
    build_motion_space(directory / "jump.mspace", clips, body.F, name="jump",
                       parameters={"layout": chain, "names": ["jump_height"], "resolution": 5}, **cheap)
    if reach:
        clips = [SourceClip(f"reach_{h}", animate(body, reach_motion(body.skeleton, h, fps=fps)), fps, False)
                 for h in (0.9, 1.7)]
        build_motion_space(directory / "reach.mspace", clips, body.F, name="reach",
                           parameters={"layout": chain, "names": ["reach_height"], "resolution": 5}, **cheap)


def build_tiny_graph(spaces, path, *, reach=False, edges=None, **options):
    """Write the tiny graph over ``spaces`` (``build_tiny_spaces``) to ``path`` (``edges``: others
    than the tiny ones); returns its report."""
    from engine.graph.build import NodeSpec, build_graph

    spaces = Path(spaces)
    names = ("walk", "stand", "jump", "reach") if reach else ("walk", "stand", "jump")
    nodes = [NodeSpec(name, spaces / f"{name}.mspace", "stand" if name in ("jump", "reach") else None)
             for name in names]
    edges = edges if edges is not None else TINY_EDGES + (REACH_EDGES if reach else [])
    return build_graph(path, nodes, edges, name="tiny", **options)
