"""Server settings, read from the environment (``MORPHSPACE_*``) or given to ``create_app``.

``Settings()`` reads e.g. ``MORPHSPACE_DATA_DIR=/srv/morphspace MORPHSPACE_TOKEN=...``; tests build
``Settings(data_dir=tmp_path, ...)`` directly. Paths the API can reach all live under
``data_dir``: ``spaces/`` (motion spaces), ``datasets/`` (uploaded captures), ``jobs.sqlite``
and ``work/`` (job scratch space, and ``work/derived/``: arrays the blenders derive from the
spaces, shared by the server's processes).
"""

from __future__ import annotations

import ipaddress
from pathlib import Path

from pydantic import Field, SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="MORPHSPACE_", extra="ignore")

    data_dir: Path = Field(Path("data"), description="root of everything the server reads and writes")
    host: str = Field("127.0.0.1", description="address `morphspace serve` binds")
    port: int = Field(8000, ge=0, le=65535)
    token: SecretStr | None = Field(None, description="bearer token required by mutating endpoints")
    allow_open_bind: bool = Field(False, description="bind a non-loopback address without a token")
    cors_origins: list[str] = Field(default_factory=list, description="origins allowed by CORS")
    dask_scheduler: str | None = Field(None, description="Dask scheduler address; local workers if unset")
    job_workers: int = Field(1, ge=1, le=64, description="local worker processes for jobs")
    workers: int = Field(1, ge=1, le=64, description="server processes sharing the port (morphspace serve)")
    # uploads
    max_upload_bytes: int = Field(512 * 2**20, ge=1, description="largest accepted upload")
    max_upload_files: int = Field(20000, ge=1, description="most files in one dataset")
    max_unpacked_bytes: int = Field(4 * 2**30, ge=1, description="largest dataset once unpacked")
    max_json_bytes: int = Field(16 * 2**20, ge=1024, description="largest request body other than an upload")
    # streaming
    stream_max_message: int = Field(64 * 1024, ge=256, description="largest client message (bytes)")
    stream_max_rate: float = Field(120.0, gt=0, description="client messages per second (sustained)")
    stream_burst: int = Field(240, ge=1, description="client messages allowed in a burst")
    stream_max_fps: float = Field(120.0, gt=0, description="highest frame rate a client may ask for")
    stream_max_clients: int = Field(1000, ge=1, description="concurrent streaming connections")
    export_sync_max_vertex_frames: int = Field(1_000_000, ge=1, description="longest synchronous export (frames x "
                                               "vertices); longer clips are export jobs")
    stream_stall_timeout: float = Field(60.0, gt=0, le=3600, description="seconds a connection may take no due "
                                        "frame (reads nothing) before it is closed with code 1008")

    @property
    def spaces_dir(self) -> Path:
        return self.data_dir / "spaces"

    @property
    def datasets_dir(self) -> Path:
        return self.data_dir / "datasets"

    @property
    def work_dir(self) -> Path:
        return self.data_dir / "work"

    @property
    def derived_dir(self) -> Path:
        return self.work_dir / "derived"

    @property
    def jobs_db(self) -> Path:
        return self.data_dir / "jobs.sqlite"

    def token_value(self) -> str | None:
        return self.token.get_secret_value() if self.token is not None else None


def is_loopback(host):
    """True for addresses only this machine can reach (127.0.0.0/8, ::1, localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(settings, host):
    """Refuse to serve a non-loopback address without a token unless told to (``allow_open_bind``)."""
    if not is_loopback(host) and settings.token is None and not settings.allow_open_bind:
        raise ValueError(f"refusing to bind {host} without a token: set MORPHSPACE_TOKEN, or "
                         "MORPHSPACE_ALLOW_OPEN_BIND=1 (--allow-open-bind) to serve it unprotected")
