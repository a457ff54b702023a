"""Clip and recorded-performance downloads (issue 15, item 9): animated glTF from the server's
export endpoint, at the page's parameters, and what the user steered between Record and Stop."""

from __future__ import annotations

import json
import struct


def gltf_json(data):
    """The JSON chunk of a binary glTF."""
    assert data[:4] == b"glTF"
    length, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    return json.loads(data[20:20 + length])


def download(page, selector, tmp_path):
    with page.page.expect_download(timeout=60000) as info:
        page.page.click(selector)
    path = tmp_path / info.value.suggested_filename
    info.value.save_as(path)
    return path


def test_clip_and_recording_download_as_animated_gltf(steer_server, open_page, tmp_path):
    page = open_page(steer_server.url + "/app/?space=steer&p.speed=1.2")
    page.wait_status(lambda s: s["topologySpace"] == "steer" and s["framesDrawn"] > 2, what="the steer space")
    clip = download(page, "#download-clip", tmp_path)
    assert clip.name == "steer-clip.glb"
    doc = gltf_json(clip.read_bytes())
    assert doc["animations"] and doc["meshes"][0]["primitives"][0]["targets"]
    times = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    assert times["count"] == 61 and abs(times["max"][0] - 2.0) < 1e-6  # 2 s at 30 frames/s, both ends

    page.page.click("#record")
    assert page.page.locator("#record").get_attribute("aria-pressed") == "true"
    page.page.locator("#view").focus()
    page.page.keyboard.down("ArrowUp")
    try:
        page.wait_status(lambda s: s["targets"]["speed"] > 1.6, timeout=10, what="the recorded speed-up")
    finally:
        page.page.keyboard.up("ArrowUp")
    page.page.wait_for_function("document.getElementById('record').textContent !== 'Stop (0 s)'",
                                polling=100, timeout=10000)  # at least half a second recorded
    recording = download(page, "#record", tmp_path)
    assert recording.name == "steer-recording.glb"
    doc = gltf_json(recording.read_bytes())
    times = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    assert times["count"] >= 15  # 0.5 s or more at 30 frames/s
    assert page.page.locator("#record").get_attribute("aria-pressed") == "false"
    assert page.errors() == []
