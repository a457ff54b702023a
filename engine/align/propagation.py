"""Propagating the pairwise alignment over the shape similarity tree (Casas et al. 2012, 3.2).

``aligned = align_tree(aligner, meshes, tree)`` aligns every frame from its parent's aligned
pose, from the root outwards, so every frame gets the root's vertices and faces. The tree is
cut into connected pieces (:func:`partition_tree`); each piece is aligned in order by
:func:`engine.align.pieces.align_piece`, and pieces whose parent piece is done run at the same
time in worker processes. The result does not depend on the number of workers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from engine.align.pieces import align_piece, init_worker, piece_task, portable_aligner, run_piece

RETRY_FACTOR = 1.8  # a frame scoring above this many times the median so far tries other parents (was 2.5)
MOMENTUM = 0.5  # share of the last step (grandparent -> parent) a frame in line in time starts ahead by


@dataclass
class AlignedFrames:
    """Every frame in the root mesh's topology.

    Attributes
    ----------
    vertices : (N, n, 3) float array   aligned vertices per frame
    faces : (m, 3) int array           the root mesh's faces
    residual : (N,) float array        mean two-sided distance to each frame's surface (m)
    residual_max : (N,) float array
    distortion : (N,) float array      see :class:`PairAlignment`
    seconds : (N,) float array         time spent on each frame (all attempts; wall clock)
    parent : (N,) int array            the frame each was finally aligned from (-1 for the root)
    retried : (N,) bool array          frames whose first alignment was poor and that were
                                       aligned again from other frames
    pulled : (N,) int array            limbs pulled onto what nothing covered in each frame's
                                       alignment (:mod:`engine.align.reach`; 0 without ``reach_limbs``)
    root : int
    cpu_seconds : (N,) float array     CPU time of the aligning process per frame (target
                                       surface set-up and all attempts; all its threads), which
                                       other load on the machine does not inflate
    root_vertices : (n, 3) float array   the root mesh as every frame numbers its vertices (the
                                       captured root without its floating fragments)
    root_kept : (n,) int array         index of each in the captured root mesh's vertices
    distortion_tail : (N,) float array see :class:`PairAlignment`
    colour : (N,) float array          mean RGB distance between the root's colours and each frame's
                                       where its vertices landed (the root's: against its own surface;
                                       NaN without colours; :mod:`engine.align.appearance`)
    confidence : (N,) float array      0..1, see :func:`engine.align.repair.alignment_confidence`
    repaired : (N,) bool array         frames the repair pass aligned again from other sources
    poses : dict                       frame -> aligned tet vertices (k, 3) (not written out)
    repair_spent : int                 pairwise alignments the repair pass spent (not written out)
    repair_stopped : list of str       the repair's phases ("root", "others", ...) that ended before their
                                       last frame because a run of alignments had stopped mending frames
                                       (``min_yield`` of :func:`engine.align.repair.repair_alignment`)
    """

    vertices: np.ndarray
    faces: np.ndarray
    residual: np.ndarray
    residual_max: np.ndarray
    distortion: np.ndarray
    seconds: np.ndarray
    parent: np.ndarray
    retried: np.ndarray
    root: int
    cpu_seconds: np.ndarray = None
    root_vertices: np.ndarray = None
    root_kept: np.ndarray = None
    distortion_tail: np.ndarray = None
    colour: np.ndarray = None
    confidence: np.ndarray = None
    repaired: np.ndarray = None
    poses: dict = None
    pulled: np.ndarray = None
    repair_spent: int = 0
    repair_stopped: list = None


def partition_tree(parent, order, chunk):
    """Cut a rooted tree into connected pieces of about ``chunk`` frames (alignment tasks).

    Parameters
    ----------
    parent : (N,) int array   -1 for the root
    order : (N,) int array    breadth-first order
    chunk : int

    Returns
    -------
    task_of : (N,) int array          the piece of every frame
    heads : list of int               the first frame of each piece (its parent lies in
                                      another piece, or it is the root); piece 0 holds the root
    task_parent : (T,) int array      the piece holding each head's parent (-1 for piece 0)

    Notes
    -----
    Bottom-up: a frame whose not-yet-assigned subtree reaches ``chunk`` frames starts a piece.
    Pieces depend on each other only through their heads' parents, so pieces whose parent
    piece is done can be aligned at the same time.
    """
    parent = np.asarray(parent)
    order = np.asarray(order)
    N = len(parent)
    pending = np.ones(N, dtype=np.int64)
    cut = np.zeros(N, dtype=bool)
    for node in order[:0:-1]:
        if pending[node] >= chunk:
            cut[node] = True
        else:
            pending[parent[node]] += pending[node]
    cut[order[0]] = True
    heads = [int(node) for node in order if cut[node]]
    task_of = np.full(N, -1, dtype=np.int64)
    for t, head in enumerate(heads):
        task_of[head] = t
    for node in order[1:]:
        if task_of[node] < 0:
            task_of[node] = task_of[parent[node]]
    task_parent = np.array([-1] + [int(task_of[parent[h]]) for h in heads[1:]], dtype=np.int64)
    return task_of, heads, task_parent


def align_tree(aligner, meshes, tree, *, yaw=None, dissimilarity=None, retries=3, retry_factor=RETRY_FACTOR, chunk=48,
               workers=1, progress=None, runner=None, lengths=None, momentum=MOMENTUM):
    """Align every frame along a rooted tree, each from its parent's aligned pose.

    Parameters
    ----------
    aligner : PairwiseAligner       built on the root frame's mesh
    meshes : sequence of Mesh-like (vertices, faces, colors) or (V, F[, colors]) tuples, one per
             frame; colours are used only when the aligner has root colours
    tree : engine.align.similarity_tree.SimilarityTree (or anything with root, parent, order)
    yaw : (N, N) array or None      ``yaw[i, j]`` degrees about +Y turning frame j onto frame i
                                    (from ``engine.align.similarity.dissimilarity_matrix``)
    dissimilarity : (N, N) array or None
        With it, a frame whose alignment scores poorly (``PairAlignment.quality`` above
        ``retry_factor`` times the median so far) is aligned again from up to ``retries`` other
        already aligned frames of its piece, the most similar first; the best result is kept.
    chunk : int                     frames per piece of the tree (see :func:`partition_tree`);
                                    the result does not depend on ``workers``
    workers : int                   processes aligning independent pieces at the same time
    progress : callable(done, total) or None
    runner : task runner or None    run the pieces as a task graph of this runner instead
                                    (:mod:`engine.tasks`: a piece waits for its parent piece); the
                                    result is the same
    lengths : (S,) int array or None   frames per sequence (the meshes are the sequences' frames
                                    concatenated); with them a frame whose parent and grandparent
                                    are the frames just before it in time, in order, starts from
                                    its parent's pose moved on by ``momentum`` times the last
                                    step (:func:`in_line_grandparents`): fast limbs (a hand 13 cm
                                    further at 25 frames/s) start near where they are going
    momentum : float                0 starts every frame from its parent's pose

    Returns
    -------
    AlignedFrames

    Notes
    -----
    Casas et al. 2012, section 3.2: pairwise non-rigid alignment across the branches of the
    shape similarity tree gives every frame the root's mesh structure.
    """
    N = len(meshes)
    order = np.asarray(tree.order)
    tree_parent = np.asarray(tree.parent)
    if len(order) != N or len(tree_parent) != N:
        raise ValueError(f"the tree has {len(order)} frames, there are {N} meshes")
    task_of, heads, task_parent = partition_tree(tree_parent, order, max(1, int(chunk)))
    members = [[] for _ in heads]
    for node in order:
        members[task_of[node]].append(int(node))
    use_colours = aligner.colors is not None
    behind = in_line_grandparents(tree_parent, lengths) if (lengths is not None and momentum) else np.full(N, -1)

    def job_for(t, history):
        nodes = members[t]
        entry = int(tree_parent[heads[t]]) if t > 0 else -1
        candidates = nodes + ([entry] if entry >= 0 else [])
        parents = [int(tree_parent[v]) for v in nodes]
        return {
            "nodes": nodes, "parents": parents,
            "meshes": [mesh_arrays(meshes[v], use_colours) for v in nodes],
            "hints": [None if (yaw is None or p < 0) else float(yaw[v, p]) for v, p in zip(nodes, parents)],
            "entry": entry, "entry_pose": poses.get(entry), "candidates": candidates,
            "similarity": None if dissimilarity is None else np.asarray(dissimilarity)[np.ix_(nodes, candidates)],
            "yaw_rows": None if yaw is None else np.asarray(yaw)[np.ix_(nodes, candidates)],
            "retries": int(retries) if dissimilarity is not None else 0, "retry_factor": float(retry_factor),
            "history": history,
            "momentum": [int(behind[v]) for v in nodes], "momentum_weight": float(momentum),
        }

    n = aligner.n_vertices
    vertices = np.zeros((N, n, 3))
    residual, residual_max = np.zeros(N), np.zeros(N)
    distortion, tail, seconds, cpu_seconds = np.zeros(N), np.zeros(N), np.zeros(N), np.zeros(N)
    colour = np.full(N, np.nan)
    parent = tree_parent.copy()
    retried = np.zeros(N, dtype=bool)
    pulled = np.zeros(N, dtype=np.int64)
    poses = {}
    qualities = [None] * len(heads)
    done = 0

    def history(t):
        found, u = [], task_parent[t]
        while u >= 0:
            found.extend(qualities[u])
            u = task_parent[u]
        return found

    def tick():
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, N)

    def collect(t, out):
        idx = np.asarray(out["nodes"])
        vertices[idx] = np.stack(out["V"])
        residual[idx], residual_max[idx] = out["residual"], out["residual_max"]
        distortion[idx], seconds[idx] = out["distortion"], out["seconds"]
        tail[idx], colour[idx] = out["tail"], out["colour"]
        cpu_seconds[idx] = out["cpu_seconds"]
        parent[idx], retried[idx], pulled[idx] = out["parent"], out["retried"], out["pulled"]
        poses.update(out["poses"])
        qualities[t] = out["quality"]

    children = [[] for _ in heads]
    for t in range(1, len(heads)):
        children[task_parent[t]].append(t)
    if progress is not None:  # the stage shows from its start (a runner reports only as pieces finish)
        progress(0, N)
    if runner is not None:
        jobs = [job_for(t, None) for t in range(len(heads))]  # entry pose and history: from the parent task
        outs = runner.tree(piece_task, jobs, task_parent.tolist(), shared=portable_aligner(aligner),
                           sizes=[len(m) for m in members], progress=progress)
        for t, out in enumerate(outs):
            collect(t, out)
    elif workers <= 1 or len(heads) == 1:
        stack = [0]
        while stack:
            t = stack.pop(0)
            collect(t, align_piece(aligner, job_for(t, history(t)), tick=tick))
            stack.extend(children[t])
    else:
        import multiprocessing
        import queue as queue_module
        from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

        context = multiprocessing.get_context("forkserver")
        ticks = context.Queue()
        state = (aligner.V, aligner.F, aligner.colors, (aligner.V_tet, aligner.T), aligner.options, aligner.seed)
        with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=init_worker,
                                 initargs=(state, ticks)) as pool:
            running = {pool.submit(run_piece, job_for(0, [])): 0}
            while running:
                finished, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
                while True:
                    try:
                        ticks.get_nowait()
                    except queue_module.Empty:
                        break
                    tick()
                for future in finished:
                    t = running.pop(future)
                    collect(t, future.result())
                    for c in children[t]:
                        running[pool.submit(run_piece, job_for(c, history(c)))] = c
        if progress is not None:
            progress(N, N)  # ticks still in the queue
    return AlignedFrames(vertices=vertices, faces=aligner.F.copy(), residual=residual, residual_max=residual_max,
                         distortion=distortion, seconds=seconds, parent=parent, retried=retried,
                         root=int(tree.root), cpu_seconds=cpu_seconds, root_vertices=aligner.V.copy(),
                         root_kept=np.arange(len(aligner.V)), distortion_tail=tail, colour=colour,
                         poses=poses, pulled=pulled)


def in_line_grandparents(parent, lengths):
    """Per frame, its grandparent when grandparent, parent and frame follow each other in time.

    Parameters
    ----------
    parent : (N,) int array    the tree's parent of every frame (-1 at the root)
    lengths : (S,) int array   frames per sequence, concatenated in order

    Returns
    -------
    (N,) int array   g = parent[parent[f]] where f - parent[f] == parent[f] - g == +-1 and the
                     three frames are in one sequence; -1 elsewhere
    """
    parent = np.asarray(parent, dtype=np.int64)
    sequence = np.repeat(np.arange(len(lengths)), np.asarray(lengths, dtype=np.int64))
    if len(sequence) != len(parent):
        raise ValueError(f"lengths add up to {len(sequence)} frames, the tree has {len(parent)}")
    frame = np.arange(len(parent))
    p = parent
    g = np.where(p >= 0, parent[np.maximum(p, 0)], -1)
    step = frame - p
    line = (p >= 0) & (g >= 0) & (np.abs(step) == 1) & (p - g == step)
    safe_p, safe_g = np.maximum(p, 0), np.maximum(g, 0)
    line &= (sequence[safe_p] == sequence) & (sequence[safe_g] == sequence)
    return np.where(line, g, -1)


def mesh_arrays(mesh, use_colours):
    """(V, F, colors or None) arrays of a Mesh-like or a (V, F[, colors]) tuple."""
    if hasattr(mesh, "vertices"):
        V, F, C = mesh.vertices, mesh.faces, getattr(mesh, "colors", None)
    else:
        V, F, C = mesh[0], mesh[1], (mesh[2] if len(mesh) > 2 else None)
    return (np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64),
            None if (C is None or not use_colours) else np.asarray(C, dtype=np.float64))


__all__ = ["AlignedFrames", "MOMENTUM", "RETRY_FACTOR", "align_tree", "in_line_grandparents", "mesh_arrays",
           "partition_tree"]
