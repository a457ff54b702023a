"""Speed ramps for gaits that start from or stop to a standing pose (``motions.gait(ramp=...)``).

A ramp scales a straight gait by an *amount* a(t) in [0, 1]: 1 is the full gait, 0 standing
still. The root's speed is ``a(t) * speed`` and its travelled distance the exact integral of it,
so footfalls stay planted while the steps shorten to nothing (stop) or grow from nothing (start).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.synthetic.kinematics import smoothstep


@dataclass(frozen=True)
class Ramp:
    """A cubic ease of the gait amount between ``start`` and ``end`` seconds.

    kind : "stop" (amount 1 -> 0) or "start" (0 -> 1)
    start, end : float   seconds on the motion's clock, start < end
    """

    kind: str
    start: float
    end: float

    def __post_init__(self):
        if self.kind not in ("stop", "start"):
            raise ValueError(f"ramp kind must be 'stop' or 'start', got {self.kind!r}")
        if not self.end > self.start:
            raise ValueError(f"ramp end ({self.end}) must come after its start ({self.start})")

    def amount(self, t):
        """(frames,) gait amount a(t) in [0, 1]."""
        up = smoothstep(self.start, self.end, t)
        return 1.0 - up if self.kind == "stop" else up

    def distance(self, t, speed):
        """(frames,) root distance travelled since t = 0: the integral of speed * a(t).

        Notes
        -----
        With u = (t - start) / (end - start) clipped to [0, 1], the integral of the smoothstep
        3u^2 - 2u^3 is u^3 - u^4 / 2 (times the ramp's length).
        """
        t = np.asarray(t, dtype=float)
        span = self.end - self.start
        u = np.clip((t - self.start) / span, 0.0, 1.0)
        eased = u**3 - 0.5 * u**4
        if self.kind == "stop":
            return speed * (np.minimum(t, self.start) + span * (u - eased))
        return speed * (span * eased + np.maximum(t - self.end, 0.0))
