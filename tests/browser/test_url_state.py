"""The view's state lives in the URL (issue 15 item 4): a link through the server's `/` keeps it,
a reload keeps what the user changed, and the share link opens the same view."""

from __future__ import annotations

from urllib.parse import parse_qs, urlsplit

import pytest


def settled(page, space):
    return page.wait_status(lambda s: s["topologySpace"] == space and s["frame"] is not None
                            and s["frame"]["ack"] >= s["lastParamsSeq"], timeout=20, what=f"{space} streaming")


def test_a_link_through_the_root_opens_that_view(steer_server, open_page):
    """Failed before: `/` redirected to `/app/` without the query, so the default space opened."""
    page = open_page(steer_server.url + "/?space=jump&mode=linear&heatmap=1&scale=5&camera=side&p.jump_distance=0.9")
    assert urlsplit(page.page.url).path == "/app/"
    status = page.wait_status(lambda s: s["topologySpace"] == "jump" and s["frame"] and s["frame"]["errorMax"] is not None,
                              timeout=20, what="the jump space in linear mode with the heatmap")
    assert status["mode"] == "linear" and status["frame"]["mode"] == "linear" and status["heatmap"]
    assert status["targets"]["jump_distance"] == pytest.approx(0.9)
    assert status["camera"]["preset"] == "side" and status["heatScale"] == pytest.approx(0.005)
    assert page.page.is_checked("#heatmap") and page.page.input_value("#heat-scale") == "5"
    assert page.errors() == []


def test_a_reload_keeps_mode_heatmap_and_sliders(steer_server, open_page):
    """Failed before: a reload dropped the blend mode, the heatmap and the slider values."""
    page = open_page(steer_server.url + "/app/?space=steer")
    settled(page, "steer")
    page.page.click("#modes label:has-text('non-linear')")
    page.page.check("#heatmap")
    page.page.locator("#param-speed").fill("2.3")
    page.page.locator("#param-turn_rate").fill("-12")
    page.page.select_option("#camera", "front")
    page.wait_status(lambda s: s["frame"]["mode"] == "nonlinear" and s["targets"]["speed"] == pytest.approx(2.3, abs=0.01),
                     what="the changes applied")
    page.page.wait_for_function("location.search.includes('p.turn_rate=-12') && location.search.includes('camera=front')",
                                polling=100, timeout=5000)  # the URL is written at most every 250 ms
    query = parse_qs(urlsplit(page.page.url).query)
    assert query["mode"] == ["nonlinear"] and query["heatmap"] == ["1"] and query["space"] == ["steer"]
    page.page.reload(wait_until="load")
    status = settled(page, "steer")
    assert status["mode"] == "nonlinear" and status["heatmap"] and status["camera"]["preset"] == "front"
    assert status["targets"]["speed"] == pytest.approx(2.3, abs=0.01)
    assert status["targets"]["turn_rate"] == pytest.approx(-12, abs=0.1)
    assert float(page.page.input_value("#param-speed")) == pytest.approx(2.3, abs=0.01)
    assert page.page.is_checked("#heatmap")
    assert page.page.is_checked("#modes input[value=nonlinear]")
    assert page.errors() == []


def test_the_share_link_opens_the_same_view(steer_server, open_page):
    page = open_page(steer_server.url + "/app/?space=steer&p.speed=1.1")
    settled(page, "steer")
    page.page.click("#modes label:has-text('linear') >> nth=0")
    page.page.locator("#param-turn_rate").fill("20")
    page.wait_status(lambda s: s["frame"]["mode"] == "linear" and s["targets"]["turn_rate"] == pytest.approx(20, abs=0.1),
                     what="linear, turning")
    page.page.click("#share")
    field = page.page.locator("#share-url")
    field.wait_for(state="visible")
    link = field.input_value()
    assert page.page.evaluate("document.activeElement.id") == "share-url"
    page.screenshot("share-link")
    page.page.keyboard.press("Escape")
    field.wait_for(state="hidden")
    other = open_page(link)
    status = settled(other, "steer")
    assert status["mode"] == "linear"
    assert status["targets"]["speed"] == pytest.approx(1.1, abs=0.01)
    assert status["targets"]["turn_rate"] == pytest.approx(20, abs=0.1)
    assert page.errors() == [] and other.errors() == []


def test_a_refused_rate_or_smoothing_in_the_link_falls_back_to_the_defaults(steer_server, open_page):
    """(a docs-only user found rate=1000 or smoothing=-1 leaving the page dead: the server refused the
    hello, and every later hello repeated it)"""
    page = open_page(steer_server.url + "/app/?space=steer&rate=1000&smoothing=-1")
    status = settled(page, "steer")
    assert status["frame"]["ack"] >= 0 and page.errors() == []  # streaming: the hello was accepted


def test_a_space_the_server_cannot_play_is_said_and_replaced(steer_server, open_page):
    """(a docs-only user found an unknown space in the link replaced without a word)"""
    page = open_page(steer_server.url + "/app/?space=nosuch")
    page.wait_status(lambda s: s["topologySpace"] not in (None, "nosuch") and s["frame"] is not None, what="another space")
    page.page.wait_for_function("document.getElementById('messages').textContent.includes('space \"nosuch\" is not on "
                                "this server')", polling=50, timeout=5000)
    assert page.errors() == []
