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
