"""The page at five window sizes (issue 15 item 3, deliverable 2): nothing overlaps, every control
can be reached, the 3D view keeps most of the window. Screenshots: tests/browser/artifacts/layout-*.png."""

from __future__ import annotations

import pytest

SIZES = [(1920, 1080, False), (1400, 900, False), (1024, 768, False), (600, 800, False), (390, 844, True)]

# Boxes over (or beside) the 3D view that must not cover each other. The messages top right are
# passing notes (they let clicks through) and are left out.
BOXES_JS = """() => {
  const box = (el) => { const r = el.getBoundingClientRect(); return {x: r.x, y: r.y, w: r.width, h: r.height}; };
  const shown = (el) => el && el.offsetParent !== null && getComputedStyle(el).visibility !== 'hidden';
  const out = {};
  for (const el of document.querySelectorAll('#toolbar > *')) if (shown(el)) out['toolbar:' + el.id || el.className] = box(el);
  for (const id of ['status', 'legend', 'help', 'stick', 'view', 'toolbar']) {
    const el = document.getElementById(id);
    if (shown(el)) out[id] = box(el);
  }
  const panel = document.getElementById('panel');
  out.panelShown = shown(panel) && panel.getBoundingClientRect().left < innerWidth - 1;
  if (out.panelShown) out.panel = box(panel);
  return out;
}"""

# Every control of the panel: scrolled into view, inside the window and on top at its centre.
REACH_JS = """() => {
  const missed = [];
  const controls = document.querySelectorAll('#panel input, #panel select, #panel button, #panel a.button');
  let count = 0;
  for (const el of controls) {
    if (el.offsetParent === null || el.type === 'file' || el.closest('[hidden]')) continue;
    count += 1;
    el.scrollIntoView({block: 'center', inline: 'nearest'});
    const r = el.getBoundingClientRect();
    const x = r.x + Math.min(r.width / 2, 8), y = r.y + r.height / 2;
    const hit = document.elementFromPoint(x, y);
    const inside = r.left >= 0 && r.right <= innerWidth + 0.5 && r.top >= 0 && r.bottom <= innerHeight + 0.5;
    const ok = hit && (hit === el || el.contains(hit) || hit.contains(el) || (el.labels && [...el.labels].some(l => l.contains(hit))));
    if (!inside || !ok) missed.push(`${el.id || el.name || el.textContent.trim()}: ${inside ? 'covered by ' + (hit && (hit.id || hit.tagName)) : 'outside the window'}`);
  }
  return {count, missed};
}"""


def overlaps(a, b):
    return a["x"] < b["x"] + b["w"] - 0.5 and b["x"] < a["x"] + a["w"] - 0.5 and \
        a["y"] < b["y"] + b["h"] - 0.5 and b["y"] < a["y"] + a["h"] - 0.5


@pytest.mark.parametrize("width, height, touch", SIZES, ids=[f"{w}x{h}" for w, h, _ in SIZES])
def test_nothing_overlaps_and_every_control_is_reachable(steer_server, open_page, width, height, touch):
    page = open_page(steer_server.url + "/app/?space=steer&heatmap=1", viewport={"width": width, "height": height},
                     touch=touch)
    page.wait_status(lambda s: s["topologySpace"] == "steer" and s["framesDrawn"] > 3, what="the steer space")
    page.page.locator("#legend").wait_for(state="visible")
    boxes = page.page.evaluate(BOXES_JS)
    page.screenshot(f"layout-{width}x{height}")
    view = boxes.pop("view")
    toolbar = boxes.pop("toolbar")
    narrow = width <= 900
    assert boxes.pop("panelShown") is not narrow  # a drawer below 900 px, closed at first
    panel = boxes.pop("panel", None)
    # the 3D view: most of what the panel leaves, under the toolbar
    assert view["w"] >= (width - (panel["w"] if panel else 0)) - 1 and view["h"] >= height - toolbar["h"] - 1
    assert view["y"] >= toolbar["y"] + toolbar["h"] - 0.5
    if panel:
        assert not overlaps(panel, view) and not overlaps(panel, toolbar)
    names = sorted(boxes)
    for i, a in enumerate(names):
        box = boxes[a]
        assert box["x"] >= 0 and box["y"] >= 0 and box["x"] + box["w"] <= width + 0.5 and box["y"] + box["h"] <= height + 0.5, \
            f"{a} leaves the window: {box}"
        for b in names[i + 1:]:
            assert not overlaps(box, boxes[b]), f"{a} {box} overlaps {b} {boxes[b]}"
    if narrow:
        assert page.page.locator("#title").is_visible()
        assert "stick" in boxes if touch else True
        assert page.page.locator("#status").evaluate("e => e.classList.contains('compact')") is (width <= 700)
        page.page.click("#drawer-toggle")
        page.page.wait_for_function("getComputedStyle(document.getElementById('panel')).transform === 'none'",
                                    polling=50, timeout=5000)
        page.screenshot(f"layout-{width}x{height}-drawer")
    reach = page.page.evaluate(REACH_JS)
    assert reach["count"] > 25 and reach["missed"] == [], reach
    if narrow:  # Escape closes the drawer and gives focus back to its button
        page.page.locator("#space").focus()
        page.page.keyboard.press("Escape")
        assert page.page.evaluate("document.activeElement.id") == "drawer-toggle"
    assert page.errors() == []
