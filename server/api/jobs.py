"""Jobs: create (ingest, align, build), get, list, cancel. (Being written: see server/jobs/.)"""

from fastapi import APIRouter

router = APIRouter(tags=["jobs"])
