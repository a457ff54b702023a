"""Feet that stay put across transitions: ``FootPins`` holds a foot that is on the ground where it
is by moving its lower leg, and lets it catch up while it is in the air.

Blending two motions (a walk into a jump's take-off, a landing into a stride) moves a foot that
both of them keep on the ground: the two poses place it differently and the blend weight slides
it from one place to the other. Moving the root against the drift (the earlier foot lock) can
hold only one foot, and makes the root step where the blend does not. Here the root moves as the
blend says and each foot is held on its own: while a transition blends (and after it, for as
long as a held foot stays planted), a foot that is planted is moved back by its drift between
two consecutive frames (the horizontal travel of its pivot, the on-ground vertex that moved
least: ``clock.foot_slide``). Planted: on the ground in both frames shown, and planted in the
motions blended (``contact_table``: in a source clip a foot is planted where one of its vertices
on the ground moves slower than ``speed`` in the clip's own world; a blend of clips plants it
where their weights, and across a transition the blend weight, give planted clips the larger
share), so a swinging foot that skims the ground is not held back. The offset is carried by the
whole leg (``engine.graph.legs.LegRig``): the foot moves as a whole, the thigh turns about the
hip and the knee flexes so that thigh and shin keep their lengths (lengthening by 3% at most when
a straight leg must reach); an offset the leg cannot reach or longer than ``cap`` x the leg's
length is shortened to what it can (the foot then slides by the rest). While the foot is not planted its offset shrinks at ``release`` m/s, so
it lands where the motion puts it; a foot that never lifts (a stand) keeps its offset.

Notes: the same idea as footskate clean-up for skeletons (Kovar, Schreiner, Gleicher, SCA 2002),
done on the mesh: no skeleton, the legs found on the rest mesh by height and side.
"""

from __future__ import annotations

import math

import numpy as np

from engine.blend.phase import phase_of_sample, phase_samples
from engine.graph.clock import contact_moves
from engine.graph.compiled import contact_moves as compiled_contact_moves
from engine.graph.legs import LegRig


def contact_table(space, feet, ground, *, speed=0.25):
    """(N, P, feet) bool: source clip i of ``space`` plants foot k at phase sample p: one of the
    foot's vertices is below ``ground`` (root-local y) and moves slower than ``speed`` m/s in the
    clip's own world (its change over the phase samples, plus the clip's root step and turn)."""
    blender, track = space.blender("linear"), space.root_track
    n_sources, n_phases, cyclic = space.n_sources, space.n_phases, bool(space.cyclic)
    index = np.concatenate(feet)
    bounds = np.cumsum([0] + [len(f) for f in feet])
    out = np.zeros((n_sources, n_phases, len(feet)), dtype=bool)
    phases = [phase_of_sample(p, n_phases, cyclic) for p in range(n_phases)]
    for i in range(n_sources):
        w = np.zeros(n_sources)
        w[i] = 1.0
        L = np.stack([np.array(blender.blend(w, phase), dtype=np.float64)[index] for phase in phases])  # (P, F, 3)
        if cyclic:
            dL = (np.roll(L, -1, axis=0) - np.roll(L, 1, axis=0)) * (n_phases / 2.0)
        else:
            dL = np.gradient(L, 1.0 / (n_phases - 1), axis=0)
        rate, turn = track.root_rate[:, i, :], track.turn_rate[:, i]
        for p, phase in enumerate(phases):
            r0, r1, a = phase_samples(phase, len(turn), cyclic)
            step = (1 - a) * rate[r0] + a * rate[r1]
            omega = (1 - a) * turn[r0] + a * turn[r1]
            vx = dL[p, :, 0] + step[0] + omega * L[p, :, 2]   # per unit phase, in the root's frame
            vz = dL[p, :, 2] + step[2] - omega * L[p, :, 0]
            moving = np.hypot(vx, vz) / float(track.durations[i])
            still = (L[p, :, 1] < ground) & (moving < speed)
            for k in range(len(feet)):
                out[i, p, k] = bool(still[bounds[k]:bounds[k + 1]].any())
    return out


class FootPins:
    """The horizontal world offsets (one (2,) xz vector per foot) that hold the feet.

    Parameters
    ----------
    rest : (n, 3) float array     the rest mesh (the nodes' shared topology)
    feet : list of (f,) int arrays   each foot's vertices (``clock.foot_vertices``)
    ground : float                height under which a vertex is on the ground (root-local y)
    release : float               m/s an offset shrinks by while its foot is not planted
    creep : float                 m/s it shrinks by while the foot stays planted after the blend
                                  (a stand never lifts a foot; 2 cm/s is the captured walk's own
                                  drift of the sole)
    cap : float                   the longest offset, as a fraction of the leg's length
                                  (``LegRig``; 0.2: 16 cm on the demo body)
    stretch : float               how much longer thigh and shin may become to reach (``LegRig``)
    """

    def __init__(self, rest, feet, ground, *, release=1.0, creep=0.02, cap=0.2, stretch=0.03):
        self.feet, self.ground = list(feet), float(ground)
        self._bounds = np.cumsum([0] + [len(f) for f in self.feet]).tolist()  # stacked feet: foot k's rows
        self._bounds_array = np.array(self._bounds, dtype=np.int64)
        self.release, self.creep = float(release), float(creep)
        self.rig = LegRig(rest, self.feet, cap=cap, stretch=stretch)
        self.offsets = np.zeros((len(self.feet), 2))
        self._unheld = self.offsets.tolist()
        self.shortened = 0.0   # metres of offset the legs could not carry so far (the feet slid by it)

    def planted(self, node, weights, phase):
        """(feet,) float: the share of ``node``'s clips at ``weights`` that plant each foot at
        ``phase`` (the contact table cached on the node)."""
        table = node.cached("contacts", lambda: contact_table(node.space, self.feet, self.ground).astype(float))
        n_phases = table.shape[1]
        p = int(round(phase * (n_phases if node.cyclic else n_phases - 1))) % n_phases
        w = np.asarray(weights, dtype=float).tolist()  # (a few sources and two feet: Python floats)
        total = sum(w)
        rows = table[:, p, :].tolist()
        return np.array([sum(x * row[k] for x, row in zip(w, rows)) / total for k in range(table.shape[2])])

    def holding(self):
        """Some foot is held away from where the motion puts it."""
        return self.offsets.tolist() != self._unheld  # a list compare: numpy's any() costs more on 4 numbers

    def apply(self, mesh, heading):
        """Hold the feet of root-local ``mesh`` (n, 3) float32 (the motion's, not held yet) at the
        offsets, in place, for a root turned by ``heading``: the legs carry what they can reach
        and the offsets are shortened to it (``LegRig.deform``)."""
        self.rig.move(mesh, *self.prepare(mesh, heading))

    def prepare(self, mesh, heading, known=None):
        """``apply`` up to the vertex work: the root-local offsets, the share of each the legs
        carry on ``mesh`` and the joints (``LegRig.move``'s arguments); the offsets are shortened
        to what the legs carry. ``known``: the joints already found on ``mesh`` (``LegRig.reach``)."""
        c, s = math.cos(heading), math.sin(heading)
        local = np.zeros((len(self.feet), 3))  # world -> root-local, per foot
        for k, (ox, oz) in enumerate(self.offsets.tolist()):
            local[k, 0], local[k, 2] = c * ox - s * oz, s * ox + c * oz
        shares, joints = self.rig.reach(mesh, local, known)
        if (shares < 1.0).any():
            before = np.hypot(self.offsets[:, 0], self.offsets[:, 1])
            self.offsets *= shares[:, None]
            self.shortened += float((before * (1.0 - shares)).sum())
        return local, shares, joints

    def update(self, before, now, planted, dt, *, blending):
        """Hold or release each foot between two shown frames; returns the (feet, 2) change of
        the offsets (to shift the mesh already shown by).

        before, now : list of (f, 3) float arrays   each foot's world vertices in the two frames
                      (or each one (F, 3) array: the feet's vertices stacked, in ``feet``'s order)
        planted : (feet,) bool   the motions blended plant the foot now (``planted`` >= 0.5)
        blending : bool   a transition is blending (a foot not held yet is held only then)
        """
        if not isinstance(before, np.ndarray):
            before = np.concatenate(before)
        if not isinstance(now, np.ndarray):
            now = np.concatenate(now)
        if before.dtype == now.dtype == np.float32:  # the pivots' moves (clock.foot_slide), compiled
            moves, found = compiled_contact_moves(before, now, self.ground, self._bounds_array)
            moves = [m if f else None for m, f in zip(moves.tolist(), found.tolist())]
        else:
            moves = [None if m is None else m.tolist() for m in contact_moves(before, now, self.ground, self._bounds)]
        planted = np.asarray(planted).tolist()
        change = [[0.0, 0.0] for _ in moves]
        offsets = self.offsets.tolist()
        for k, move in enumerate(moves):  # (on Python floats: two feet of two numbers)
            held = offsets[k] != [0.0, 0.0]
            if planted[k] and move is not None and (blending or held):
                change[k] = [-move[0], -move[1]]             # planted: stay where it was
                if not blending:                             # after the blend: creep back, slowly
                    toward = self._towards_zero(offsets[k][0] + change[k][0], offsets[k][1] + change[k][1],
                                                self.creep * dt)
                    change[k] = [change[k][0] + toward[0], change[k][1] + toward[1]]
            elif held and not planted[k]:                    # moving: catch up with the motion
                change[k] = self._towards_zero(offsets[k][0], offsets[k][1], self.release * dt)
        for k, (dx, dz) in enumerate(change):
            x, z = offsets[k][0] + dx, offsets[k][1] + dz
            offsets[k] = [x, z] if math.hypot(x, z) >= 1e-6 else [0.0, 0.0]
        self.offsets[:] = offsets
        return np.array(change)

    @staticmethod
    def _towards_zero(x, z, distance):
        """The change [dx, dz] that shortens the offset (x, z) by at most ``distance``."""
        length = math.hypot(x, z)
        if length == 0.0:
            return [0.0, 0.0]
        share = min(length, distance) / length
        return [-x * share, -z * share]
