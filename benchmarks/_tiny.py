"""What the benchmarks' ``--tiny`` smoke runs share (a module, not a benchmark: no ``--tiny`` of its own)."""

from __future__ import annotations

TINY_VERTICES = 1000
TINY_FPS = 15.0


def parse_arguments(parser, argv, tiny_defaults):
    """``parser.parse_args(argv)``; with ``--tiny``, ``tiny_defaults`` replace the defaults (options
    given on the command line still win) and ``--out`` is required, so a tiny run never replaces
    the recorded results."""
    args = parser.parse_args(argv)
    if args.tiny:
        if args.out is None:
            parser.error("--tiny needs --out (a tiny run never replaces the recorded results)")
        parser.set_defaults(**tiny_defaults)
        args = parser.parse_args(argv)
    return args


def build_tiny_speed_space(path, n_vertices=TINY_VERTICES, fps=TINY_FPS):
    """Build a two-gait speed space at ``path``: a slow walk (0.8 m/s) and a jog (2.8 m/s) of a
    1,000-vertex body (``n_vertices``) at 15 fps (``fps``) straight from the generator, in a speed chain,
    epsilon 5 mm (a few seconds at 1,000 vertices). Returns the body (engine.synthetic.Body)."""
    from engine.motion_space import SourceClip, build_motion_space  # not for parse_arguments' users
    from engine.parameters import Layout
    from engine.synthetic import animate, build_body, gait

    body = build_body(n_vertices)
    clips = []
    for name, speed in (("walk_slow", 0.8), ("jog", 2.8)):
        motion = gait(body.skeleton, speed, fps=fps, cycles=2.0)
        clips.append(SourceClip(name, animate(body, motion), fps, True, motion.frames_per_cycle))
    build_motion_space(path, clips, body.F, name=path.stem, epsilon=0.005, rest=body.V,
                       parameters={"layout": Layout("chain", 2, chain=(0, 1)), "names": ["speed"]})
    return body


def emit(record, out):
    """Print ``record`` as indented JSON and, with ``out`` (a Path), write it there too."""
    import json

    text = json.dumps(record, indent=1)
    print(text)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
