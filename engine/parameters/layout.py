"""Layouts: low-dimensional sheets through the blend-weight simplex (chain, grid, fan), and the
parameter measures a space can have (``MEASURES``, with their units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


MEASURES = {
    "speed": "m/s", "turn_rate": "deg/s", "jump_height": "m", "jump_distance": "m", "reach_height": "m",
}


@dataclass(frozen=True)
class Layout:
    """A sheet of blend weights with coordinates u in [0, 1]^dims.

    Attributes
    ----------
    kind : "chain", "grid" or "fan"
    n_sources : int
    chain : tuple of int     sources in parameter order (chain, and the fan's speed chain)
    corners : tuple of int   grid: sources at u = (0, 0), (1, 0), (0, 1), (1, 1)
    left, right : int        fan: the turning sources
    """

    kind: str
    n_sources: int
    chain: tuple = ()
    corners: tuple = ()
    left: int = -1
    right: int = -1

    def __post_init__(self):
        used = {"chain": self.chain, "grid": self.corners, "fan": self.chain + (self.left, self.right)}
        if self.kind not in used:
            raise ValueError(f"unknown layout {self.kind!r}; choose chain, grid or fan")
        sources = used[self.kind]
        if self.kind == "chain" and len(self.chain) < 2:
            raise ValueError("a chain layout needs at least 2 sources")
        if self.kind == "grid" and len(self.corners) != 4:
            raise ValueError("a grid layout needs exactly 4 corner sources")
        if self.kind == "fan" and (len(self.chain) < 1 or self.left < 0 or self.right < 0):
            raise ValueError("a fan layout needs a speed chain and a left and a right turn")
        if len(set(sources)) != len(sources) or any(not 0 <= s < self.n_sources for s in sources):
            raise ValueError(f"layout {self.kind}: sources must be distinct indices below {self.n_sources}")

    @property
    def dims(self):
        return 1 if self.kind == "chain" else 2

    def _chain_weights(self, u, chain, w, share=1.0):
        """Add ``share`` of the chain's weights at u in [0, 1] into the list w."""
        if len(chain) == 1:
            w[chain[0]] += share
            return
        x = min(max(u, 0.0), 1.0) * (len(chain) - 1)
        i = min(int(x), len(chain) - 2)
        a = x - i
        w[chain[i]] += share * (1.0 - a)
        w[chain[i + 1]] += share * a

    def weights(self, u):
        """(N,) blend weights (summing to 1) at sheet coordinates u (dims,).

        Plain Python on the one or two coordinates: the player asks every frame."""
        u = [min(max(float(x), 0.0), 1.0) for x in (u if isinstance(u, list) else np.atleast_1d(u).tolist())]
        w = [0.0] * self.n_sources
        kind, chain = self.kind, self.chain
        if kind == "fan" and len(chain) == 2:  # _chain_weights of a two-source chain, inline
            d = 2.0 * u[1] - 1.0
            share, a = 1.0 - abs(d), u[0]
            w[chain[0]] += share * (1.0 - a)
            w[chain[1]] += share * a
            w[self.left] += max(d, 0.0)
            w[self.right] += max(-d, 0.0)
        elif kind == "chain":
            self._chain_weights(u[0], self.chain, w)
        elif kind == "grid":
            a, b = u
            for corner, coefficient in zip(self.corners, ((1 - a) * (1 - b), a * (1 - b), (1 - a) * b, a * b)):
                w[corner] += coefficient
        else:
            d = 2.0 * u[1] - 1.0  # direction: -1 right, +1 left
            self._chain_weights(u[0], self.chain, w, 1.0 - abs(d))
            w[self.left] += max(d, 0.0)
            w[self.right] += max(-d, 0.0)
        return np.array(w)

    def to_dict(self):
        return {"kind": self.kind, "n_sources": self.n_sources, "chain": list(self.chain),
                "corners": list(self.corners), "left": self.left, "right": self.right}

    @classmethod
    def from_dict(cls, d):
        return cls(kind=d["kind"], n_sources=d["n_sources"], chain=tuple(d.get("chain", ())),
                   corners=tuple(d.get("corners", ())), left=d.get("left", -1), right=d.get("right", -1))
