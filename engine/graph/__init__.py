"""Motion graphs (Casas et al., 4D Parametric Motion Graphs, I3D 2012): nodes are motion spaces,
edges allowed transitions; a build precomputes window dissimilarities for every edge
(``build``), the run-time search picks when to leave, where to enter and how long to blend
(``search``), and the player plays the graph (``player``)."""

from engine.graph.build import GRAPH_FORMAT, GRAPH_VERSION, GraphError, NodeSpec, build_graph
from engine.graph.features import WindowOptions
from engine.graph.graph import MotionGraph
from engine.graph.player import GraphFrame, GraphPlayer
from engine.graph.search import SearchOptions, Transition, TransitionSearch

__all__ = ["GRAPH_FORMAT", "GRAPH_VERSION", "GraphError", "NodeSpec", "build_graph", "WindowOptions",
           "MotionGraph", "GraphFrame", "GraphPlayer", "SearchOptions", "Transition", "TransitionSearch"]
