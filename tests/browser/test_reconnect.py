"""The page survives a server restart: it says it is reconnecting, then resumes the stream on the
same space with the parameters the user had asked for."""

from __future__ import annotations


def test_the_page_resumes_frames_after_the_server_restarts(restartable_server, open_page):
    server = restartable_server
    page = open_page(server.url + "/app/?space=speed")
    page.wait_frames(5)
    slider = page.page.locator("#param-speed")
    high = float(slider.get_attribute("max"))
    slider.fill(str(high))
    asked = page.wait_status(lambda s: s["frame"]["ack"] >= s["lastParamsSeq"] > 0, what="the new speed applied")

    server.stop()
    page.wait_status(lambda s: s["connection"] == "reconnecting", timeout=10, what="the page to notice")
    assert page.page.locator("#conn").inner_text().startswith("reconnecting")
    page.screenshot("reconnect-server-down")
    frames_before = page.status()["stats"]["framesTotal"]

    server.start()  # the same port
    status = page.wait_status(lambda s: s["connection"] == "open" and s["stats"]["framesTotal"] > frames_before + 5,
                              timeout=20, what="frames from the restarted server")
    assert status["reconnects"] >= 1 and status["space"] == "speed"
    # the new session was started with the speed the user had set
    status = page.wait_status(lambda s: s["requested"] and abs(s["requested"]["speed"] - asked["targets"]["speed"]) < 0.02,
                              what="the requested speed to carry over")
    page.screenshot("reconnect-resumed")
    # only the expected noise: failed WebSocket/fetch attempts while the server was down
    unexpected = page.errors(ignore=("WebSocket connection", "ERR_CONNECTION_REFUSED", "Failed to load resource"))
    assert unexpected == []


def test_the_page_leaves_a_server_that_went_silent(restartable_server, open_page):
    """A server that stops sending without closing the socket (stopped with SIGSTOP: a machine gone
    from the network looks the same) is left after connection.js's SILENCE_MS, 5 s without a
    message while frames are due, and reconnected to once it answers again."""
    import os
    import signal
    import time

    server = restartable_server
    page = open_page(server.url + "/app/?space=speed")
    page.wait_frames(5)
    os.killpg(server.process.pid, signal.SIGSTOP)
    try:
        stopped = time.monotonic()
        page.wait_status(lambda s: s["connection"] == "reconnecting", timeout=15, what="the page to notice the silence")
        noticed = time.monotonic() - stopped
    finally:
        os.killpg(server.process.pid, signal.SIGCONT)
    assert 4.5 <= noticed <= 9.0, noticed
    frames_before = page.status()["stats"]["framesTotal"]
    status = page.wait_status(lambda s: s["connection"] == "open" and s["stats"]["framesTotal"] > frames_before + 5,
                              timeout=20, what="frames from the server once it runs again")
    assert status["reconnects"] >= 1 and status["space"] == "speed"
    unexpected = page.errors(ignore=("WebSocket connection", "ERR_CONNECTION_REFUSED", "Failed to load resource"))
    assert unexpected == []


def test_a_failing_listing_of_spaces_is_said_with_its_reason_until_it_lists_again(restartable_server, open_page):
    """The page's first GET /v1/spaces fails (a proxy in front of the server answers 503 three
    times): the page says why and that it retries, keeps saying so, then says the spaces are
    listed again and plays; it never claims the server has no space."""
    failures = []

    def listing(route):
        if len(failures) < 3:
            failures.append(route.request.url)
            route.fulfill(status=503, content_type="application/json", body='{"detail": "upstream down for maintenance"}')
        else:
            route.continue_()

    page = open_page(restartable_server.url + "/app/?space=speed", routes=[("**/v1/spaces", listing)])
    messages = page.page.locator("#messages")
    messages.locator(".message", has_text="upstream down for maintenance").wait_for(timeout=15000)
    assert "retrying every second" in messages.inner_text()
    messages.locator(".message", has_text="listed again").wait_for(timeout=15000)
    page.wait_frames(5)
    assert len(failures) == 3 and page.status()["space"] == "speed"
    assert "No playable motion space" not in messages.inner_text()
    assert page.errors(ignore=("Failed to load resource",)) == []
