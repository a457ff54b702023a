"""The heatmap's auto scale while paused (issue 15 item 5): the legend and the colours follow
the frame on screen."""

from __future__ import annotations

import numpy as np
import pytest


def test_auto_scale_recolours_the_paused_frame(web_server, open_page):
    """Failed before: ticking auto while paused set the legend to 0.05 / 0.1 mm (no frame arrived
    to measure) and left the colours on the fixed scale."""
    page = open_page(web_server.url + "/app/?space=speed&mode=linear&heatmap=1&scale=1000")
    page.wait_status(lambda s: s["frame"] and s["frame"]["mode"] == "linear" and s["frame"]["errorMax"],
                     timeout=20, what="linear frames with distances")
    page.page.click("#pause")
    paused = page.wait_status(lambda s: s["paused"] and s["frame"]["ack"] >= s["lastParamsSeq"], what="the pause")
    before = np.asarray(page.page.evaluate("window.morphspace.viewer.vertexColours()"))
    image_before = page.canvas_pixels("heatmap-paused-1000mm")
    largest = page.status()["frame"]["errorMax"]
    assert 0 < largest < 0.4  # well under the 1 m red end the URL set (seen: 16 to 72 mm)
    page.page.check("#heat-auto")
    status = page.status()
    assert status["heatScale"] == pytest.approx(largest, rel=1e-6)
    legend = page.page.locator("#legend-max").inner_text()
    assert float(legend.split()[1]) == pytest.approx(largest * 1000, rel=0.01), legend
    after = np.asarray(page.page.evaluate("window.morphspace.viewer.vertexColours()"))
    assert np.abs(after - before).max() > 0.3, "the mesh kept its colours"
    page.page.evaluate("new Promise(done => requestAnimationFrame(() => requestAnimationFrame(done)))")
    image_after = page.canvas_pixels("heatmap-paused-auto")
    changed = np.abs(image_after.astype(int) - image_before.astype(int)).max(axis=2) > 30
    assert changed.mean() > 0.002, f"only {changed.mean():.3%} of the pixels changed"
    assert paused["paused"] and page.errors() == []


def test_a_scale_that_is_not_millimetres_above_0_is_refused(web_server, open_page):
    """(a docs-only user found -5 kept in the field and written to the address, the legend silently
    staying at 20 mm)"""
    page = open_page(web_server.url + "/app/?space=speed&heatmap=1&scale=7")
    page.wait_status(lambda s: s["frame"] and s["heatmap"], timeout=20, what="the heatmap on")
    field = page.page.locator("#heat-scale")
    field.fill("-5")
    field.press("Enter")
    page.page.wait_for_function("document.getElementById('messages').textContent.includes('red at: give millimetres')",
                                polling=50, timeout=5000)
    assert field.input_value() == "7" and page.status()["heatScale"] == pytest.approx(0.007)
    page.page.wait_for_timeout(400)  # the URL is written at most every 250 ms
    assert "scale=7" in page.page.url and "scale=-5" not in page.page.url
    assert page.errors() == []
