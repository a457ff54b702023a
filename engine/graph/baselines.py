"""Two simple transition strategies to measure the search against, with the search's interface
(``search(source, weights, phase, target, target_weights, ...) -> Transition``):

``ImmediateCut``: leave at once and show the target from the next frame on (a blend one
millisecond long); ``Crossfade``: leave at once and blend for a fixed length. Both enter a
one-shot at its start and a cyclic target at the source's phase.
"""

from __future__ import annotations

from engine.graph.search import SearchOptions, Transition


class _Immediate:
    length = 0.3

    def __init__(self, graph):
        self.graph = graph
        self.options = SearchOptions(lengths=(self.length,))

    def search(self, source, weights, phase, target, target_weights, *, budget=None, latency_weight=None,
               finish_by=None, early=False):
        if (source, target) not in self.graph.edges:
            from engine.graph.build import GraphError

            raise GraphError(f"graph {self.graph.name!r} has no edge {source} -> {target}")
        a, b = self.graph.node(source), self.graph.node(target)
        leave_in = 0.0
        if finish_by is not None:  # a one-shot plays on until the blend would end with it
            leave_in = max(0.0, finish_by - self.length)
        enter = phase if b.cyclic and a.cyclic else 0.0
        table = self.graph.edges[(source, target)]
        j = int(round((phase % 1.0 if a.cyclic else phase) * (len(a.samples.phases) - (0 if a.cyclic else 1))))
        e = int(round(enter * (len(b.samples.phases) - (0 if b.cyclic else 1))))
        seam = float(table[a.sample_of(weights), j % len(a.samples.phases), b.sample_of(target_weights),
                           e % len(b.samples.phases)])
        return Transition(source=source, target=target, leave_in=leave_in, leave_phase=float(phase),
                          enter_phase=float(enter), length=self.length, dissimilarity=seam, cost=0.0,
                          target_weights=target_weights)


class ImmediateCut(_Immediate):
    """Leave now; the target from the next frame."""

    length = 1e-3


class Crossfade(_Immediate):
    """Leave now; blend for ``length`` seconds (default 0.3)."""

    def __init__(self, graph, length=0.3):
        self.length = float(length)
        super().__init__(graph)
