"""The jobs panel lists the datasets already on the server (issue 15 item 8): a capture written
straight into the data directory (as scripts/demo's are) can be built from, and an aligned
dataset's pictures open in the page."""

from __future__ import annotations

import json
import time

import numpy as np
from live_server import LiveServer

FPS = 10.0


def write_capture(root, name, speeds):
    """A capture dataset on disk (no upload): <root>/<name>/sequences/<seq>/consistent/frame_NNNN.obj."""
    from engine.mesh_io import write_obj
    from engine.mesh_io.dataset import write_capture_manifest
    from engine.synthetic import animate, build_body, gait

    body = build_body(1000)
    sequences = []
    for seq, speed in speeds.items():
        frames_dir = root / name / "sequences" / seq / "consistent"
        frames_dir.mkdir(parents=True)
        frames = animate(body, gait(body.skeleton, speed, cycles=1.0, fps=FPS))
        for k, V in enumerate(frames):
            write_obj(frames_dir / f"frame_{k:04d}.obj", V, body.F, precision=6)
        meta = {"name": seq, "fps": FPS, "cyclic": True, "frames": len(frames), "topology": "consistent",
                "vertices": int(len(body.V))}
        (root / name / "sequences" / seq / "meta.json").write_text(json.dumps(meta))
        sequences.append(meta)
    write_capture_manifest(root / name, {"created": time.time(), "sequences": sequences})


def write_pictures(directory):
    from PIL import Image

    for k, picture in enumerate(("similarity.png", "tree.png", "aligned_pattern.png")):
        Image.fromarray(np.full((40, 60 + 10 * k, 3), 60 * k, dtype=np.uint8)).save(directory / picture)


def test_datasets_on_the_server_are_listed_built_from_and_pictured(tmp_path, open_page):
    """Failed before: the panel listed nothing and offered only an upload."""
    data = tmp_path / "data"
    write_capture(data / "datasets", "demo", {"slow": 0.9, "fast": 2.6})
    write_capture(data / "datasets", "demo_aligned", {"walk": 1.2, "jog": 2.2})
    write_pictures(data / "datasets" / "demo_aligned")
    manifest = json.loads((data / "datasets" / "demo_aligned" / "manifest.json").read_text())
    (data / "datasets" / "demo_aligned" / "manifest.json").write_text(json.dumps({**manifest, "aligned": True}))
    with LiveServer(data) as server:
        page = open_page(server.url + "/app/")
        rows = page.page.locator("#datasets li[data-name]")
        rows.first.wait_for(timeout=15000)
        assert rows.evaluate_all("els => els.map(e => e.dataset.name)") == ["demo", "demo_aligned"]
        demo = page.page.locator("#datasets li[data-name=demo]")
        assert "capture · 2 sequences" in demo.inner_text()
        assert "aligned" in page.page.locator("#datasets li[data-name=demo_aligned]").inner_text()
        assert demo.locator("button[data-action=pictures]").count() == 0

        # the pictures of the aligned one, in a dialog, loaded
        page.page.click("#datasets li[data-name=demo_aligned] button[data-action=pictures]")
        page.page.locator("#pictures-dialog").wait_for(state="visible")
        page.page.wait_for_function("[...document.querySelectorAll('#pictures img')].length === 3 && "
                                    "[...document.querySelectorAll('#pictures img')].every(i => i.complete && i.naturalWidth > 0)",
                                    polling=100, timeout=10000)
        page.screenshot("jobs-pictures")
        page.page.keyboard.press("Escape")
        page.page.locator("#pictures-dialog").wait_for(state="hidden")

        # build from the captured dataset: its Build button fills the form
        page.page.click("#datasets li[data-name=demo] button[data-action=build]")
        assert page.page.input_value("#build-dataset") == "demo"
        assert page.page.evaluate("document.activeElement.id") == "build-dataset"
        assert sorted(page.page.locator("#build-sources input:checked").evaluate_all("els => els.map(e => e.value)")) \
            == ["fast", "slow"]
        page.page.fill("#build-space", "from_demo")
        page.page.fill("#build-phases", "8")
        page.page.fill("#build-epsilon", "10")
        page.page.click("#build-button")
        status = page.wait_status(lambda s: s["topologySpace"] == "from_demo" and s["stats"]["framesTotal"] > 5,
                                  timeout=120, what="the space built from the listed dataset to stream")
        assert "from_demo" in status["spaces"]
        assert page.errors() == []
