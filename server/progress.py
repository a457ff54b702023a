"""Progress display for long CLI work: one tqdm bar per stage, on stderr.

Engine functions report ``progress(stage, done, total)``; ``StageBars()`` is such a callable.
"""

from __future__ import annotations

import sys

from tqdm import tqdm


class StageBars:
    """Callable ``(stage, done, total)`` showing a bar per stage; a new stage closes the last."""

    def __init__(self, *, leave=True):
        self.leave = leave
        self.stage, self.bar = None, None

    def __call__(self, stage, done, total):
        if stage != self.stage:
            self.close()
            self.stage = stage
            self.bar = tqdm(total=total or None, desc=stage, unit="step", dynamic_ncols=True, mininterval=0.5,
                            file=sys.stderr, leave=self.leave)
        if total:
            self.bar.total = total
        if done >= self.bar.n:
            self.bar.update(done - self.bar.n)  # redrawn at most every mininterval (logs stay short)
        else:
            self.bar.n = done
            self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar, self.stage = None, None
