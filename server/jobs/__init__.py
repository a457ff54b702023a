"""The job service: persistent job records and the executors that run them."""

from server.jobs.service import JobService

__all__ = ["JobService"]
