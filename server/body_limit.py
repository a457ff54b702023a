"""A bound on request bodies other than dataset uploads (which stream to disk under their own
limit, ``MORPHSPACE_MAX_UPLOAD_BYTES``): JSON requests are parsed whole in memory, so one over
``MORPHSPACE_MAX_JSON_BYTES`` is answered 413 before any of it reaches the application."""

from __future__ import annotations

import json

UPLOAD_PATH = "/v1/datasets"


class BodyLimit:
    """ASGI middleware: a request body (other than ``POST /v1/datasets``) larger than ``limit``
    bytes is answered 413 naming the setting, whether its ``Content-Length`` says so or its
    chunks add up to it; a smaller body is read here and handed on unchanged."""

    def __init__(self, app, limit):
        self.app, self.limit = app, int(limit)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] in ("GET", "HEAD", "OPTIONS") or (
                scope["method"] == "POST" and scope["path"] == UPLOAD_PATH):
            return await self.app(scope, receive, send)
        declared = dict(scope.get("headers") or []).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.limit:
            return await self._refuse(send, int(declared), declared=True)
        messages, size = [], 0
        while True:
            message = await receive()
            messages.append(message)
            if message["type"] != "http.request":
                break   # the client went away: the application sees that as it would have
            size += len(message.get("body", b""))
            if size > self.limit:
                return await self._refuse(send, size, declared=False)
            if not message.get("more_body", False):
                break

        async def replay():
            return messages.pop(0) if messages else await receive()

        return await self.app(scope, replay, send)

    async def _refuse(self, send, size, declared):
        body = json.dumps({"detail": f"the request body is {'' if declared else 'at least '}{size} bytes; "
                                     f"the limit is {self.limit} bytes (MORPHSPACE_MAX_JSON_BYTES)"}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})
