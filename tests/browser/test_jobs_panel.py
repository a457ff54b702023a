"""The jobs panel end to end: upload a capture zip, start a build, watch its progress bar, and the
new motion space appears in the picker and streams (the server starts with no spaces at all)."""

from __future__ import annotations

import io
import json
import tempfile
import time
import zipfile
from pathlib import Path

SEQUENCES = {"slow": 0.9, "fast": 2.6}
BODY_VERTICES = 1000  # the smallest synthetic body: the build takes 10-20 s here


def capture_zip(fps=10.0):
    """Two one-cycle synthetic gaits at BODY_VERTICES vertices as <sequence>/frame_NNNN.obj + meta.json."""
    from engine.mesh_io import write_obj
    from engine.synthetic import animate, build_body, gait

    body = build_body(BODY_VERTICES)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive, tempfile.TemporaryDirectory() as tmp:
        for name, speed in SEQUENCES.items():
            for k, frame in enumerate(animate(body, gait(body.skeleton, speed, cycles=1.0, fps=fps))):
                path = Path(tmp) / f"{name}_{k}.obj"
                write_obj(path, frame, body.F, precision=6)
                archive.write(path, f"{name}/frame_{k:04d}.obj")
            archive.writestr(f"{name}/meta.json", json.dumps({"fps": fps, "cyclic": True}))
    return buffer.getvalue()


def test_upload_build_and_the_new_space_streams(empty_server, open_page):
    page = open_page(empty_server.url + "/app/")
    page.wait_status(lambda s: s["spaces"] == [] and s["space"] is None, what="an empty space list")
    # the status shows the empty list before the page's first REST answer lands; the message follows it
    page.page.locator("#messages .message", has_text="No playable motion space").wait_for(timeout=15000)

    page.page.set_input_files("#upload-file", files=[
        {"name": "my gaits.zip", "mimeType": "application/zip", "buffer": capture_zip()}])
    assert page.page.input_value("#upload-name") == "my_gaits"
    page.page.click("#upload-button")
    page.page.locator("#build-form").wait_for(state="visible", timeout=30000)
    assert page.page.input_value("#build-dataset") == "my_gaits"
    assert sorted(page.page.locator("#build-sources input:checked").evaluate_all("els => els.map(e => e.value)")) \
        == sorted(SEQUENCES)
    page.page.select_option("#build-layout", "chain")
    page.page.fill("#build-space", "gaitspace")
    page.page.fill("#build-phases", "8")
    page.page.fill("#build-epsilon", "10")
    page.page.click("#build-button")

    job = page.page.locator("#job-list li").first
    job.wait_for(timeout=10000)
    assert "build gaitspace" in job.inner_text()
    progress = []
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        state = job.get_attribute("data-status")
        progress.append(float(job.locator("progress").get_attribute("value") or 0))
        if state == "running" and progress[-1] > 0 and not any(p > 0 for p in progress[:-1]):
            page.screenshot("jobs-build-running")
        if state in ("succeeded", "failed", "cancelled"):
            break
        page.page.wait_for_timeout(100)  # the page polls every 0.7 s; the build takes a few seconds
    assert state == "succeeded", job.inner_text()
    assert progress[-1] == 1.0 and any(0 < p < 1 for p in progress), progress

    status = page.wait_status(lambda s: s["topologySpace"] == "gaitspace" and s["stats"]["framesTotal"] > 5,
                              timeout=20, what="the new space to stream")
    assert "gaitspace" in status["spaces"]
    assert page.page.input_value("#space") == "gaitspace"
    page.screenshot("jobs-new-space-streaming")
    assert page.errors() == []
