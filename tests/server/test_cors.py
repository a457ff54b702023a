"""CORS is off unless configured, and then allows exactly the configured origins."""

import httpx

from live_server import LiveServer, data_dir_with_spaces


def test_cors_allows_only_configured_origins(built_spaces, tmp_path):
    data = data_dir_with_spaces(tmp_path / "data", built_spaces, names=("speed",))
    env = {"MORPHSPACE_CORS_ORIGINS": '["https://viewer.example"]'}
    with LiveServer(data, env=env) as live:
        ok = httpx.get(live.url + "/v1/spaces", headers={"Origin": "https://viewer.example"})
        assert ok.headers.get("access-control-allow-origin") == "https://viewer.example"
        other = httpx.get(live.url + "/v1/spaces", headers={"Origin": "https://evil.example"})
        assert "access-control-allow-origin" not in other.headers
        preflight = httpx.options(live.url + "/v1/jobs", headers={
            "Origin": "https://viewer.example", "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "authorization"})
        assert preflight.status_code == 200


def test_no_cors_headers_by_default(server):
    r = httpx.get(server.url + "/v1/spaces", headers={"Origin": "https://viewer.example"})
    assert "access-control-allow-origin" not in r.headers
