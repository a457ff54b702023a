"""The page with a keyboard only, in a narrow window (600x800): the toolbar, the drawer, the help
dialog and steering are all reachable and leave focus where it makes sense."""

from __future__ import annotations


def tab_to(page, element_id, limit=40, back=False):
    for _ in range(limit):
        if page.page.evaluate("document.activeElement && document.activeElement.id") == element_id:
            return
        page.page.keyboard.press("Shift+Tab" if back else "Tab")
    raise AssertionError(f"#{element_id} not reached in {limit} presses of {'Shift+' if back else ''}Tab")


def focused(page):
    return page.page.evaluate("document.activeElement && document.activeElement.id")


def test_keyboard_only_in_a_narrow_window(steer_server, open_page):
    page = open_page(steer_server.url + "/app/?space=steer&p.speed=1.2", viewport={"width": 600, "height": 800})
    page.wait_status(lambda s: s["topologySpace"] == "steer" and s["framesDrawn"] > 2, what="the steer space")
    # the drawer: Enter opens it with focus on the space picker, Esc closes it back to its button
    tab_to(page, "drawer-toggle")
    page.page.keyboard.press("Enter")
    page.page.wait_for_function("document.activeElement.id === 'space'", polling=50, timeout=5000)
    tab_to(page, "param-speed")  # a focused slider takes its own arrows
    before = page.status()["targets"]["speed"]
    page.page.keyboard.press("ArrowRight")
    page.wait_status(lambda s: s["targets"]["speed"] > before, what="the slider's own arrow key")
    page.page.keyboard.press("Escape")
    assert focused(page) == "drawer-toggle"
    assert page.page.locator("#drawer-toggle").get_attribute("aria-expanded") == "false"
    # the help dialog from its button: focus inside, Tab kept inside, Esc back to the button
    tab_to(page, "help-button", back=True)
    page.page.keyboard.press("Enter")
    page.page.locator("#help-dialog").wait_for(state="visible")
    assert focused(page) == "help-close"
    page.page.keyboard.press("Tab")
    assert focused(page) == "help-close"  # the only control of the dialog
    page.page.keyboard.press("Escape")
    page.page.locator("#help-dialog").wait_for(state="hidden")
    assert focused(page) == "help-button"
    # on to the 3D view: the arrows steer
    tab_to(page, "view")
    start = page.status()["targets"]["speed"]
    page.page.keyboard.down("ArrowUp")
    try:
        page.wait_status(lambda s: s["targets"]["speed"] > start + 0.1, timeout=10, what="ArrowUp to speed up")
    finally:
        page.page.keyboard.up("ArrowUp")
    page.page.keyboard.press("Space")
    page.wait_status(lambda s: s["paused"], what="Space to pause")
    page.page.keyboard.press("c")
    page.wait_status(lambda s: s["camera"]["preset"] == "side", what="C to the side camera")
    assert page.errors() == []
