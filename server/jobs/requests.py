"""Job requests checked against the data directory before anything is queued.

``RequestCheck(settings, registry).params(request, store)`` gives the parameters a job record
stores (with ``output_name`` and ``output_type``: what the job will write) or raises
``JobRequestError`` with the HTTP status and a message naming the problem: a dataset, space or
graph that does not exist, an output that exists or that another job is already writing, an
align job's sequences and root, a build's sources, an export's clip.
"""

from __future__ import annotations

from server import uploads
from server.jobs import models
from server.jobs.tasks import JobError, _relative, align_sequences, check_build_sources


class JobRequestError(Exception):
    """A job request that cannot be accepted: HTTP ``status`` and a message."""

    def __init__(self, status, message):
        super().__init__(message)
        self.status, self.message = status, message


class RequestCheck:
    """The checks of one server process (it keeps the graphs beside the registry's spaces)."""

    def __init__(self, settings, registry):
        self.settings, self.registry = settings, registry
        self._graphs = None

    def params(self, request, store):
        """A validated request (models.JobRequest) checked against the data directory and the
        jobs in ``store``: the parameters to queue it with."""
        params = request.model_dump()
        kind = params["kind"]
        if kind == "export":
            # the job record shows what the export uses: a graph's recording carries its own clip
            drop = models.CLIP_ONLY if params.get("graph") is not None else ("graph", "recording")
            params = {k: v for k, v in params.items() if k not in drop}
            self._check_export(params)
            params["output_name"], params["output_type"] = None, "export"
            return params
        datasets = self.settings.datasets_dir
        inputs = params["datasets"] if kind == "align" else [] if kind == "graph" else [params["dataset"]]
        for name in inputs:
            if not (datasets / name).is_dir():
                have = ", ".join(uploads.dataset_names(self.settings)) or "none"
                raise JobRequestError(404, f"no dataset {name!r} (have: {have})")
        if kind == "align":
            self._check_align(params)
        if kind == "build":
            try:
                check_build_sources(datasets / params["dataset"], params["spec"])
            except JobError as exc:
                raise JobRequestError(422, str(exc)) from None
            rest = params["spec"].get("rest")
            if rest and not (datasets / params["dataset"] / rest).is_file():
                raise JobRequestError(422, f"dataset {params['dataset']!r} has no {rest}")
            target, what = self.settings.spaces_dir / f"{params['space']}.mspace", "space"
            output = params["space"]
        elif kind == "graph":
            spaces = self.settings.spaces_dir
            missing = [n["space"] for n in params["nodes"] if not (spaces / f"{n['space']}.mspace").is_file()]
            if missing:
                raise JobRequestError(404, f"no space(s) {', '.join(repr(m) for m in missing)}")
            target, what = self.settings.spaces_dir / f"{params['graph']}.mgraph", "graph"
            output = params["graph"]
        else:
            output = params.get("output") or params["dataset"]
            target, what = datasets / output, "dataset"
            if kind == "ingest" and not params.get("output"):
                params["replace"] = True  # normalising in place replaces the input when it is done
        if target.exists() and not params.get("replace"):
            raise JobRequestError(409, f"{what} {output!r} already exists; pass replace=true to replace it")
        for job in store.active_using("output_name", output):
            if job["params"].get("output_type") == what:
                raise JobRequestError(409, f"job {job['id']} is already writing {what} {output!r}")
        params["output_name"], params["output_type"] = output, what
        return params

    def _check_align(self, params):
        """An align job's ``only`` names sequences of its datasets, and its ``root`` a sequence of
        them (of ``only``, when given) and a frame within the frame files listed, or a frame
        index: refused before anything is queued, as ``morphspace align`` refuses them before it
        reads a frame. A listing that fails leaves the problem to the job, which names it."""
        from server.commands.align_inputs import check_root_early, parse_root

        try:
            sequences = align_sequences(self.settings.datasets_dir, params)
            parse_root(params.get("root"), sequences, None, label="root")  # its form and sequence
            check_root_early(params.get("root"), sequences, label="root")   # and its frame
        except (ValueError, OSError, JobError) as exc:
            raise JobRequestError(422, _relative(exc, self.settings.data_dir)) from None

    def _check_export(self, params):
        """An export job's space must exist and its clip be playable (the errors of the
        synchronous endpoint, before anything is queued)."""
        from engine.export import ClipError, check_clip
        from server.exports import clip_of
        from server.registry import BrokenSpace, UnknownSpace

        if params.get("graph") is not None:
            from server.graph_exports import check_graph_export

            if self._graphs is None:  # the graphs beside the registry's spaces
                from server.graphs import GraphRegistry

                self._graphs = GraphRegistry(self.registry)
            check_graph_export(self._graphs, params["graph"], params["recording"], JobRequestError)
            return
        try:
            space = self.registry.get(params["space"])
        except UnknownSpace as exc:
            raise JobRequestError(404, str(exc)) from None
        except BrokenSpace as exc:
            raise JobRequestError(409, str(exc)) from None
        try:
            check_clip(space, clip_of(params))
        except ClipError as exc:
            raise JobRequestError(422, str(exc)) from None
