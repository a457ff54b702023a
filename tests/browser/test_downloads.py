"""Downloads of the frame on screen (deliverable 5): OBJ and GLB from the REST API, the same pose
the page shows."""

from __future__ import annotations

import io

import numpy as np


def test_the_frame_on_screen_downloads_as_obj_and_glb(web_server, open_page, tmp_path):
    page = open_page(web_server.url + "/app/?space=speed&p.speed=2.0")
    page.wait_frames(5)
    page.page.click("#pause")
    status = page.wait_status(lambda s: s["paused"] and s["frame"]["ack"] >= s["lastParamsSeq"], what="the pause")
    page.wait_status(lambda s: s["drawnSeq"] == s["frame"]["seq"], what="the last frame drawn")
    shown = np.asarray(page.page.evaluate("Array.from(window.morphspace.viewer.mesh.geometry.attributes.position.array)"),
                       dtype=float).reshape(-1, 3)
    files = {}
    for kind in ("obj", "glb"):
        with page.page.expect_download(timeout=20000) as download:
            page.page.click(f"#download-{kind}")
        path = tmp_path / download.value.suggested_filename
        download.value.save_as(path)
        files[kind] = path
    assert files["obj"].name.startswith("speed-hybrid-phase") and files["obj"].suffix == ".obj"
    V = np.array([[float(x) for x in line.split()[1:4]] for line in files["obj"].read_text().splitlines()
                  if line.startswith("v ")])
    assert V.shape == shown.shape
    distance = np.linalg.norm(V - shown, axis=1)  # the same pose, root-local (q16 on screen)
    assert distance.max() < 0.002, distance.max()
    glb = files["glb"].read_bytes()
    assert glb[:4] == b"glTF"
    import trimesh

    mesh = trimesh.load(io.BytesIO(glb), file_type="glb", force="mesh", process=False)
    assert len(mesh.vertices) == len(shown)
    assert status["paused"] and page.errors() == []
