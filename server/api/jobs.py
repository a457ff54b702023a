"""Jobs: create (ingest, align, build), get, list, cancel (server/jobs/ runs them)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, HTTPException, Query, Response

from server.api.deps import Authorised, get_jobs
from server.jobs.models import JobList, JobRecord, JobRequest, JobStatus
from server.jobs.service import JobRequestError, JobService

router = APIRouter(tags=["jobs"])
JobsDep = Annotated[JobService, Depends(get_jobs)]

EXAMPLE_BUILD = {
    "kind": "build", "dataset": "mycapture", "space": "walk_jog",
    "spec": {"sources": ["walk", "jog"], "epsilon_mm": 5.0,
             "parameters": {"layout": "chain", "chain": ["walk", "jog"], "measures": ["speed"], "resolution": 11}},
}


def _http(exc):
    return HTTPException(exc.status, exc.message)


@router.post("/jobs", status_code=202, response_model=JobRecord, dependencies=[Authorised],
             summary="Queue a job: ingest, align, build or export",
             responses={401: {"description": "a bearer token is required"},
                        404: {"description": "no such dataset (or space)"},
                        409: {"description": "the output exists (replace=true) or another job is writing it"},
                        422: {"description": "invalid request (the message names the field or sequence)"}})
async def create_job(request: Annotated[JobRequest, Body(openapi_examples={"build": {"value": EXAMPLE_BUILD}})],
               jobs: JobsDep, response: Response):
    try:
        job = jobs.create(request)
    except JobRequestError as exc:
        raise _http(exc) from None
    response.headers["Location"] = f"/v1/jobs/{job['id']}"
    return job


@router.get("/jobs", response_model=JobList, summary="List jobs, newest first")
def list_jobs(jobs: JobsDep,
              status: Annotated[list[JobStatus] | None, Query(description="only these statuses (repeatable)")] = None,
              kind: Annotated[str | None, Query(pattern="^(build|align|ingest|export|graph)$")] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 100,
              offset: Annotated[int, Query(ge=0)] = 0):
    return {"jobs": jobs.list(status=[s.value for s in status or []], kind=kind, limit=limit, offset=offset)}


@router.get("/jobs/{job_id}", response_model=JobRecord, summary="One job: status, stage, progress, log tail, result",
            responses={404: {"description": "no such job"}})
def get_job(job_id: str, jobs: JobsDep):
    job = jobs.get(job_id)
    if job is None:
        raise HTTPException(404, f"no job {job_id!r}")
    return job


@router.post("/jobs/{job_id}/cancel", response_model=JobRecord, dependencies=[Authorised],
             summary="Cancel a queued or running job",
             responses={404: {"description": "no such job"}, 409: {"description": "the job has already finished"}})
async def cancel_job(job_id: str, jobs: JobsDep):
    try:
        return await jobs.cancel(job_id)
    except JobRequestError as exc:
        raise _http(exc) from None
