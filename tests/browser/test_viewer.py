"""The viewer in headless Chromium against a live server: it loads cleanly, draws the streamed
character, its sliders and keys steer the server's blend, and the heatmap recolours the mesh."""

from __future__ import annotations

import numpy as np
import pytest

from server import protocol as P
from server.decoding import decode_client


def character_pixels(rgb):
    """Pixels of the default (warm beige) body colour: red well above blue."""
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return (r - b > 35) & (r > 90)


def heatmap_pixels(rgb):
    """Pixels of the heatmap's cold end (blue to cyan): blue well above red."""
    r, g, b = (rgb[..., k].astype(int) for k in range(3))
    return (b - r > 60) & (b > 120)


def check_messages_decode_on_the_server(page):
    """Messages the page's JavaScript builds are exactly what server/protocol.py decodes."""
    built = page.page.evaluate("""async () => {
        const m = await import("./js/messages.js");
        const bytes = (type, fields) => Array.from(m.clientMessage(type, fields));
        let refused = null;
        try { m.clientMessage("params", { params: { speed: 1 }, bogus: 1 }); } catch (e) { refused = e.message; }
        return {
          hello: bytes("hello", { space: "speed", codec: "q16", rate: 30, mode: "linear", heatmap: true,
                                  params: { speed: 1.25 }, smoothing: 0, window: 3, seq: 1 }),
          params: bytes("params", { params: { speed: 2 }, seq: 7 }),
          ack: bytes("ack", { frame: 12 }),
          refused,
        };
    }""")
    hello = decode_client(bytes(built["hello"]))
    assert hello == P.Hello(space="speed", codec="q16", rate=30.0, mode="linear", heatmap=True,
                            params={"speed": 1.25}, smoothing=0.0, window=3, seq=1)
    assert decode_client(bytes(built["params"])) == P.Params(params={"speed": 2.0}, seq=7)
    assert decode_client(bytes(built["ack"])) == P.Ack(frame=12)
    assert "params has no field \"bogus\"" in built["refused"]


def test_page_loads_streams_and_draws_without_console_errors(web_server, open_page):
    page = open_page(web_server.url + "/")  # redirects to /app/
    assert page.page.url.startswith(web_server.url + "/app/")
    status = page.wait_status(lambda s: s["connection"] == "open" and s["topologySpace"] is not None,
                              what="a topology")
    assert set(status["spaces"]) == {"jump", "speed"}
    page.wait_frames(10)
    rgb = page.canvas_pixels("viewer-loaded", until=lambda rgb: character_pixels(rgb).mean() > 0.003)
    luminance = rgb.mean(axis=2)
    assert luminance.std() > 12, "the canvas is (nearly) uniform"
    assert len(np.unique(rgb.reshape(-1, 3) // 16, axis=0)) > 20, "too few distinct colours"
    body = character_pixels(rgb).mean()
    assert 0.003 < body < 0.5, f"the character covers {body:.2%} of the view"
    page.screenshot("page-loaded")
    status = page.status()
    assert status["stats"]["fps"] > 0 and status["errors"] == []
    assert page.errors() == [], page.errors()
    # offline: everything (three.js, msgpack, the page) comes from the server itself
    foreign = [url for url in page.requests if not url.startswith((web_server.url, web_server.ws_url, "data:"))]
    assert foreign == []
    assert any(url.endswith("/app/vendor/three/three.module.js") for url in page.requests)
    # the overlay shows the same numbers
    assert page.page.locator("#conn").inner_text() == "live"
    assert page.page.locator("#realised tbody tr").count() == len(status["realised"])
    check_messages_decode_on_the_server(page)


def wait_still(page, name, timeout=10.0):
    """Two identical consecutive canvas captures (the paused view has settled); returns one."""
    previous = page.canvas_pixels()
    for _ in range(int(timeout / 0.25)):
        page.page.wait_for_timeout(250)
        current = page.canvas_pixels()
        if np.array_equal(current, previous):
            page.save_pixels(current, name)
            return current
        previous = current
    raise AssertionError("the paused view kept changing")


def test_slider_changes_the_realised_parameters_and_the_image(web_server, open_page):
    # no smoothing, so a request while paused answers with one frame at the new parameters
    page = open_page(web_server.url + "/app/?space=speed&smoothing=0")
    page.wait_status(lambda s: s["topologySpace"] == "speed", what="the speed space")
    page.wait_frames(5)
    slider = page.page.locator("#param-speed")
    low, high = float(slider.get_attribute("min")), float(slider.get_attribute("max"))
    page.page.click("#pause")
    page.page.uncheck("#follow")  # a still camera: only the parameter changes the picture
    slider.fill(str(low))
    before = page.wait_status(lambda s: s["paused"] and s["frame"]["ack"] >= s["lastParamsSeq"],
                              what="the frame answering the low speed")
    image_low = wait_still(page, "slider-low-speed")

    slider.fill(str(high))
    after = page.wait_status(lambda s: s["frame"]["ack"] >= s["lastParamsSeq"] > before["lastParamsSeq"],
                             what="the frame answering the high speed")
    assert after["targets"]["speed"] == pytest.approx(high, abs=0.01 * (high - low))  # the slider step
    realised_low, realised_high = before["realised"]["speed"], after["realised"]["speed"]
    assert realised_low == pytest.approx(low, abs=0.1 * (high - low))
    assert realised_high == pytest.approx(high, abs=0.1 * (high - low))
    assert realised_high - realised_low > 0.5 * (high - low)
    assert after["stats"]["latency"]["n"] >= 1
    # the overlay prints the realised value the server reported
    page.page.wait_for_function(
        "v => Math.abs(Number(document.querySelector('#realised tr[data-name=speed] .realised').textContent) - v) < 0.01",
        arg=realised_high, polling=100, timeout=3000)  # the overlay refreshes five times a second
    image_high = wait_still(page, "slider-high-speed")
    changed = np.abs(image_high.astype(int) - image_low.astype(int)).max(axis=2) > 30
    assert changed.mean() > 0.002, f"only {changed.mean():.3%} of the pixels changed"
    page.screenshot("slider-high-speed-page")
    assert page.errors() == []


def test_keyboard_steering_and_the_trail(web_server, open_page):
    page = open_page(web_server.url + "/app/?space=speed")
    page.wait_frames(3)
    page.page.fill("#trail-every", "2")
    page.page.check("#trail")
    start = page.status()["targets"]["speed"]
    page.page.locator("#view").click()
    page.page.keyboard.down("ArrowUp")
    page.page.wait_for_timeout(700)
    page.page.keyboard.up("ArrowUp")
    status = page.wait_status(lambda s: s["targets"]["speed"] > start + 0.1
                              and s["realised"]["speed"] > start + 0.05, timeout=10,
                              what="the realised speed to rise")
    page.page.keyboard.down("KeyS")
    page.page.wait_for_timeout(700)
    page.page.keyboard.up("KeyS")
    page.wait_status(lambda s: s["targets"]["speed"] < status["targets"]["speed"] - 0.1, timeout=5,
                     what="the target speed to fall")
    page.wait_status(lambda s: page.page.evaluate("window.morphspace.viewer.trail.meshes.length") >= 3,
                     timeout=20, what="three trail snapshots")
    page.canvas_pixels("trail")
    assert page.errors() == []


def test_heatmap_and_blend_mode_change_the_colours(web_server, open_page):
    page = open_page(web_server.url + "/app/?space=speed")
    page.wait_frames(5)
    plain = page.canvas_pixels("heatmap-off", until=lambda rgb: character_pixels(rgb).mean() > 0.003)
    assert character_pixels(plain).mean() > 0.003
    blue_plain = heatmap_pixels(plain).mean()  # the path line and the origin's z axis are blue too

    page.page.click("#modes label:has-text('linear')")
    page.page.check("#heatmap")
    status = page.wait_status(lambda s: s["frame"]["mode"] == "linear" and s["frame"]["errorMax"] is not None,
                              timeout=20, what="linear frames carrying the heatmap")
    assert status["heatmap"] and status["frame"]["errorMax"] > 0, "linear blending should differ from non-linear"
    page.wait_frames(3)
    coloured = page.canvas_pixels("heatmap-linear",
                                  until=lambda rgb: heatmap_pixels(rgb).mean() > max(0.003, 3 * blue_plain))
    blue_heatmap = heatmap_pixels(coloured).mean()
    assert blue_heatmap > max(0.003, 3 * blue_plain), f"no heatmap colours on the mesh ({blue_heatmap:.3%})"
    assert character_pixels(coloured).mean() < 0.5 * character_pixels(plain).mean()
    assert page.page.locator("#legend").is_visible()
    assert "max distance from non-linear" in page.page.locator("#heat-readout").inner_text()
    page.screenshot("heatmap-linear-page")

    page.page.uncheck("#heatmap")
    page.wait_status(lambda s: s["frame"]["errorMax"] is None, what="frames without the heatmap")
    page.wait_frames(2)
    assert heatmap_pixels(page.canvas_pixels()).mean() < 0.5 * blue_heatmap
    assert page.errors() == []
