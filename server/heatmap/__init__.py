"""Heatmaps off the event loop and out of the server process: per-vertex distances of streamed
frames from the non-linear blend.

A heatmap frame needs the exact non-linear blend at the frame's weights and phase: about a
millisecond of solving for 3,000 vertices, far too much per frame on the event loop that serves
every client. ``HeatmapService`` (``service.py``, on the loop) hands the work to one helper
process (``worker.py``, ``python -m server.heatmap.worker``), latest-wins: when a heatmap frame
is written, its connection has no job in flight and at most ``WAITING`` jobs are, a job for
*that* frame (its weights, phase and vertices) goes to the helper; every frame carries its
connection's newest finished result, and ``error_seq`` names the frame it describes (a viewer
colours the mesh it shows with distances a few frames old, or a few tenths of a second with
dozens of heatmap viewers, and can tell). The frames themselves never wait for it, and heatmap
frames are produced like any other (from the phase tables when the weights recur). The helper
works at most a quarter of the time (``DUTY``: it rests three times as long as each job took).

A process, not a thread: a thread of the server's own would share its interpreter lock with the
event loop, which then waited for it after every system call and every large numpy operation of
every frame (with 50 of 200 clients viewing the heatmap, 18% of the loop's samples were spent
waiting to get the lock back after one ioctl per frame). The helper opens the spaces itself
(memory-mapped, so their pages are shared) and keeps its own non-linear blender per space; it
exits when the server closes its stdin, and so when the server process ends.
"""

from server.heatmap.codec import DUTY, encode_distances
from server.heatmap.service import WAITING, HeatmapService

__all__ = ["DUTY", "WAITING", "HeatmapService", "encode_distances"]
