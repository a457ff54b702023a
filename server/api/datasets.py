"""Capture datasets: upload (zip or multipart), list, describe. (Being written.)"""

from fastapi import APIRouter

router = APIRouter(tags=["datasets"])
