"""Side by side (deliverable 7): the same pose streamed in one blend mode (left) and pulled in
another (right)."""

from __future__ import annotations

import time



def character_pixels(rgb):
    """Pixels of the body colour (warm beige): red well above blue (as in test_viewer.py)."""
    r, b = rgb[..., 0].astype(int), rgb[..., 2].astype(int)
    return (r - b > 35) & (r > 90)


def test_side_by_side_shows_two_characters(web_server, open_page):
    page = open_page(web_server.url + "/app/?space=speed&mode=linear")
    page.wait_frames(5)
    page.page.click("#compare")
    status = page.wait_status(lambda s: s["compared"] >= 5, timeout=20, what="pulled frames for the right half")
    assert page.page.locator("#compare").get_attribute("aria-pressed") == "true"
    assert page.page.locator("#compare-labels").inner_text().split() == ["linear", "non-linear"]
    # (on a loaded machine the software renderer may not have drawn both halves yet: look again)
    for _ in range(20):
        rgb = page.canvas_pixels("compare-linear-nonlinear")
        half = rgb.shape[1] // 2
        left, right = character_pixels(rgb[:, :half]).mean(), character_pixels(rgb[:, half:]).mean()
        if left > 0.003 and right > 0.003:
            break
        time.sleep(0.5)
    assert left > 0.003 and right > 0.003, (left, right)
    assert status["stats"]["gaps"] == 0  # pulled frames' numbers are not counted as lost frames
    page.page.click("#compare")
    page.wait_frames(3)
    assert page.status()["stats"]["framesTotal"] > status["stats"]["framesTotal"]
    assert page.errors() == []
