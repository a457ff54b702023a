"""JobService (being written): job records in SQLite, local or Dask executors."""


class JobService:
    def __init__(self, settings, registry):
        self.settings, self.registry = settings, registry

    async def start(self):
        return None

    async def stop(self):
        return None
