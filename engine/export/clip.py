"""A clip: what to export from a motion space, and its frames as the player plays them.

``Clip(params={"speed": 1.5}, track=[(3.0, {"speed": 2.5})], duration=10, rate=60)`` asks for
10 s at 60 frames/s starting at speed 1.5 and, from t = 3 s, heading for 2.5 m/s (the player's
critically damped smoothing takes the parameters there, as it does for a streamed client).
``play_clip(space, clip)`` steps the real-time player (engine.player) on that clock, so the
exported frames are exactly what a stream at that rate plays: root-local vertices plus the
root transform (position, heading about +Y) of every frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from engine.player import MODES, Player

MAX_FRAMES = 100_000  # about 28 minutes at 60 frames/s


class ClipError(ValueError):
    """A clip request that cannot be played (the message names the field and the problem)."""


@dataclass(frozen=True)
class Clip:
    """What to play.

    params : {name: value}   requested at t = 0 (missing ones: the middle of their range)
    track : sequence of (time (s), {name: value})   later requests, in any order
    duration : float (s)     the clip covers [0, duration]; frames at k / rate, both ends included
    rate : float (frames/s)
    mode : "linear", "hybrid" or "nonlinear" blending
    smoothing : float (s)    time constant of the player's parameter spring
    """

    params: dict = field(default_factory=dict)
    track: tuple = ()
    duration: float = 10.0
    rate: float = 60.0
    mode: str = "hybrid"
    smoothing: float = 0.25

    @property
    def n_frames(self):
        return int(math.floor(self.duration * self.rate + 1e-9)) + 1


@dataclass
class ClipFrames:
    """The played frames of a clip.

    times : (f,) float64 seconds; local : (f, n, 3) float32 root-local vertices
    root_position : (f, 3) float64 (m); heading : (f,) float64 (rad about +Y)
    faces : (m, 3) int64; params : (f, k) float64 realised parameters; names : parameter names
    rate : frames/s; space : its name (a graph's, for a graph performance); notes : what was clamped
    nodes : list of str or None   a graph performance's node shown by each frame
    """

    times: np.ndarray
    local: np.ndarray
    root_position: np.ndarray
    heading: np.ndarray
    faces: np.ndarray
    params: np.ndarray
    names: list
    rate: float
    space: str
    notes: list
    nodes: list | None = None

    def __len__(self):
        return len(self.times)

    @property
    def uniform(self):
        """True when frame k is at time k / rate (a clip; a stream's recording may not be)."""
        return bool(np.allclose(self.times, np.arange(len(self.times)) / self.rate, rtol=0, atol=1e-9))

    def world(self, k):
        """(n, 3) float32 world vertices of frame k, computed as the player places them."""
        c, s = math.cos(self.heading[k]), math.sin(self.heading[k])
        RT = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]], dtype=np.float32)
        out = np.empty_like(self.local[k])
        np.matmul(self.local[k], RT, out=out)
        for axis, x in enumerate(self.root_position[k].tolist()):
            if x != 0.0:
                out[:, axis] += np.float32(x)
        return out


def parse_track(document, source="track"):
    """(params, [(time, params), ...]) from ``{"params": {...}, "track": [{"time": T, "params": {...}}]}``
    (both keys optional); errors name ``source`` and the entry."""
    if not isinstance(document, dict):
        raise ClipError(f"{source}: expected a JSON object with params and track")
    unknown = sorted(set(document) - {"params", "track"})
    if unknown:
        raise ClipError(f"{source}: unknown key(s) {', '.join(unknown)}; expected params and track")
    params = document.get("params") or {}
    if not isinstance(params, dict):
        raise ClipError(f"{source}: params must be an object {{name: value}}")
    entries = document.get("track") or []
    if not isinstance(entries, list):
        raise ClipError(f"{source}: track must be a list of {{time, params}}")
    track = []
    for i, entry in enumerate(entries):
        if not (isinstance(entry, dict) and set(entry) == {"time", "params"} and isinstance(entry["params"], dict)
                and isinstance(entry["time"], (int, float)) and not isinstance(entry["time"], bool)):
            raise ClipError(f"{source}: track[{i}] must be {{\"time\": seconds, \"params\": {{name: value}}}}, "
                            f"got {entry!r}")
        track.append((float(entry["time"]), dict(entry["params"])))
    return dict(params), track


def check_clip(space, clip):
    """Raise ClipError unless ``clip`` can be played on ``space`` (names, ranges, sizes)."""
    pmap = space.parameter_map
    if pmap is None:
        raise ClipError(f"{space.name}: the space has no parameter map (build it from a spec with parameters)")
    if clip.mode not in MODES:
        raise ClipError(f"mode: unknown blend mode {clip.mode!r}; choose one of {', '.join(MODES)}")
    if not (math.isfinite(clip.duration) and clip.duration > 0):
        raise ClipError(f"duration must be a positive number of seconds, got {clip.duration}")
    if not (math.isfinite(clip.rate) and clip.rate > 0):
        raise ClipError(f"rate must be a positive number of frames per second, got {clip.rate}")
    if not (math.isfinite(clip.smoothing) and clip.smoothing >= 0):
        raise ClipError(f"smoothing must be a non-negative number of seconds, got {clip.smoothing}")
    if clip.n_frames > MAX_FRAMES:
        raise ClipError(f"{clip.duration:g} s at {clip.rate:g} frames/s is {clip.n_frames} frames; at most "
                        f"{MAX_FRAMES} per clip")
    names, domain = list(pmap.names), pmap.domain()
    requests = [("params", clip.params)] + [(f"track at {when:g} s", p) for when, p in clip.track]
    for when, _ in clip.track:
        if not (math.isfinite(when) and 0 <= when <= clip.duration):
            raise ClipError(f"track: time {when} is outside the clip [0, {clip.duration:g}] s")
    for where, request in requests:
        if not isinstance(request, dict):
            raise ClipError(f"{where}: expected {{name: value}}, got {type(request).__name__}")
        for key, value in request.items():
            if key not in names:
                raise ClipError(f"{where}: unknown parameter {key!r}; {space.name} has {', '.join(names)}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ClipError(f"{where}: {key} must be a finite number, got {value!r}")
            lo, hi = domain[names.index(key)]
            unit = pmap.units[names.index(key)]
            if not lo - 1e-9 * (hi - lo) <= value <= hi + 1e-9 * (hi - lo):
                raise ClipError(f"{where}: {key} = {value:g} {unit} is out of range; {space.name} spans "
                                f"{lo:.4g} to {hi:.4g} {unit}")


def play_clip(space, clip, progress=None, blender=None):
    """Play ``clip`` on ``space`` with the real-time player; returns ClipFrames.

    Frame k is the player's state after k steps of 1 / rate (frame 0: the start, at the
    origin facing +Z); a request of the track applies from the first frame at or after its
    time, as ``morphspace play --at`` does. ``progress(done, total)`` is called as frames are made.
    ``blender``: blend with this one (``blend(weights, phase)``, e.g. a thread's own, see
    MotionSpace.new_blender) instead of the space's shared player blender.
    """
    check_clip(space, clip)
    player = Player(space, mode=clip.mode, smoothing=clip.smoothing, params=clip.params or None)
    n, dt = clip.n_frames, 1.0 / clip.rate
    script = sorted(((float(t), p) for t, p in clip.track), key=lambda item: item[0])
    local = np.empty((n, space.n_vertices, 3), dtype=np.float32)
    times, heading = np.empty(n), np.empty(n)
    root, params = np.empty((n, 3)), np.empty((n, len(player.names)))
    notes = []
    if player.clamped:
        notes.append(f"t=0 s: {player._last_request.message}")
    for k in range(n):
        while script and script[0][0] <= k * dt + 1e-9:
            when, request = script.pop(0)
            solution = player.set_params(request)
            if solution.clamped:
                notes.append(f"t={when:g} s: {solution.message}")
        if k:
            player.advance(dt)
        if blender is None:
            player.frame(out=local[k], local=True)
        else:  # what Player.frame(local=True) does, with the caller's blender
            local[k] = blender.blend(player.weights, player.phase)
        times[k], heading[k] = k * dt, player.heading
        root[k], params[k] = player.position, player.realised
        if progress is not None and (k % 16 == 15 or k == n - 1):
            progress(k + 1, n)
    return ClipFrames(times=times, local=local, root_position=root, heading=heading,
                      faces=np.asarray(space.faces, dtype=np.int64), params=params, names=list(player.names),
                      rate=float(clip.rate), space=space.name, notes=notes)
