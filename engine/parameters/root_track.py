"""Blendable root motion of a space's sources on the phase grid (``RootTrack``): the blend's
duration, root displacement and turn per unit phase, and the root path they integrate to."""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RootTrack:
    """Blendable root motion of a space's sources on the phase grid.

    durations : (N,) seconds; root_rate : (P, N, 3) displacement per unit phase in the root frame;
    turn_rate : (P, N) heading change per unit phase (rad); cyclic : bool
    """

    durations: np.ndarray
    root_rate: np.ndarray
    turn_rate: np.ndarray
    cyclic: bool

    def duration(self, w):
        """Seconds of the blend (weights normalised): sum_i w_i T_i."""
        w = np.asarray(w, dtype=float)
        return float(w @ self.durations / w.sum())

    def rates(self, w):
        """(P, 3) displacement and (P,) turn per unit phase of the blend."""
        w = np.asarray(w, dtype=float) / np.sum(w)
        return np.einsum("pnc,n->pc", self.root_rate, w), self.turn_rate @ w

    def after(self, w, seconds):
        """Root after ``seconds`` at constant weights w, starting at the origin facing +Z.

        Returns position (3,) (y = 0), heading (rad) and the phase reached. Cyclic tracks repeat
        the cycle: n whole cycles compose one rigid step n times, a geometric series in the
        complex plane (z + i x turns by e^{i theta}); one-shot clips stop at their end.
        """
        duration = self.duration(w)
        position, heading = self.integrate(w)
        grid = np.linspace(0.0, 1.0, len(heading))
        cycles, phase = divmod(seconds / duration, 1.0) if self.cyclic else (0.0, min(seconds / duration, 1.0))
        step, turn = position[-1], heading[-1]
        spin = complex(math.cos(turn), math.sin(turn))
        one = complex(step[2], step[0])
        whole = one * cycles if abs(turn) < 1e-12 else one * (1 - spin ** cycles) / (1 - spin)
        h = cycles * turn
        partial = complex(np.interp(phase, grid, position[:, 2]), np.interp(phase, grid, position[:, 0]))
        end = whole + complex(math.cos(h), math.sin(h)) * partial
        return np.array([end.imag, 0.0, end.real]), h + float(np.interp(phase, grid, heading)), phase

    def integrate(self, w, samples_per_step=4):
        """Root path of one cycle (or clip) of the blend: positions (S, 3) and headings (S,) at
        phases 0 .. 1, integrating the blended rates with the heading (midpoint rule)."""
        step, turn = self.rates(w)
        P = len(step)
        phases = np.linspace(0.0, 1.0, P * samples_per_step + 1)
        grid = np.arange(P + 1) / P if self.cyclic else np.linspace(0.0, 1.0, P)
        closed_step = np.concatenate([step, step[:1]]) if self.cyclic else step
        closed_turn = np.concatenate([turn, turn[:1]]) if self.cyclic else turn
        d_phase = np.diff(phases)
        middle = 0.5 * (phases[1:] + phases[:-1])
        s = np.stack([np.interp(middle, grid, closed_step[:, c]) for c in range(3)], axis=1)
        t = np.interp(middle, grid, closed_turn)
        heading = np.concatenate([[0.0], np.cumsum(t * d_phase)])
        h_mid = 0.5 * (heading[1:] + heading[:-1])
        world = np.stack([s[:, 0] * np.cos(h_mid) + s[:, 2] * np.sin(h_mid), s[:, 1],
                          -s[:, 0] * np.sin(h_mid) + s[:, 2] * np.cos(h_mid)], axis=1) * d_phase[:, None]
        position = np.concatenate([np.zeros((1, 3)), np.cumsum(world, axis=0)])
        return position, heading
