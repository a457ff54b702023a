"""The phase grid shared by all blenders."""

from __future__ import annotations


def phase_samples(phase, n_phases, cyclic):
    """Neighbouring phase samples and the interpolation fraction for ``phase`` in [0, 1].

    Parameters
    ----------
    phase : float
    n_phases : int    P, the number of samples
    cyclic : bool

    Returns
    -------
    p0, p1 : int      samples on either side
    a : float         fraction of the way from p0 to p1

    Notes
    -----
    Cyclic grids hold P samples at k / P (phase 1 wraps to 0); non-cyclic grids hold P samples
    at k / (P - 1), from the first frame (phase 0) to the last (phase 1); phases outside [0, 1]
    are clamped.
    """
    if cyclic:
        x = (float(phase) % 1.0) * n_phases
        p0 = int(x) % n_phases
        return p0, (p0 + 1) % n_phases, x - int(x)
    x = min(max(float(phase), 0.0), 1.0) * (n_phases - 1)
    p0 = min(int(x), n_phases - 2)
    return p0, p0 + 1, x - p0


def phase_of_sample(p, n_phases, cyclic):
    """The phase in [0, 1] of sample ``p``."""
    return p / n_phases if cyclic else p / (n_phases - 1)
