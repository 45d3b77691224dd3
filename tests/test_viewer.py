"""The browser viewer at "/", in Debian's chromium driven headless by Playwright against a
live uvicorn on 127.0.0.1.

The browser is prepared outside the tests (`make browser` installs Debian's chromium; CI
runs it); without /usr/bin/chromium or the playwright package the tests are skipped.
The plan test takes a screenshot; with UNDERTOW_SCREENSHOT=1 (`make screenshot`) it
replaces docs/img/viewer.png, otherwise it goes to the test's temporary folder.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import httpx
import pytest
from service_fixtures import ROOT
from test_plots import CROSSING_SCENE

from testbed.service import LiveServer

CHROMIUM = Path("/usr/bin/chromium")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SCREENSHOT = ROOT / "docs" / "img" / "viewer.png"
"""Replaced only when UNDERTOW_SCREENSHOT=1, so a test run leaves the tree clean."""
PLAN_TIMEOUT = 180_000  # [ms]
COLORS = {"active": (255, 127, 14), "link": (43, 52, 64), "with": (31, 111, 180),
          "without": (154, 154, 154), "mark": (214, 39, 40)}


# --------------------------------------------------------------------------- set-up


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip(f"no browser at {CHROMIUM}: `make browser` installs Debian's chromium")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="the playwright package is not installed")
    sync_playwright = sync_api.sync_playwright

    with sync_playwright() as playwright:
        instance = playwright.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        yield instance
        instance.close()


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with LiveServer(tmp_path_factory.mktemp("viewer") / "jobs.sqlite3") as live:
        yield live


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1440, "height": 1000})
    view = context.new_page()
    view.page_errors = []
    view.on("pageerror", lambda error: view.page_errors.append(str(error)))
    yield view
    context.close()


# --------------------------------------------------------------------------- helpers

COUNT_COLORS = """([id, colors]) => {
  const c = document.getElementById(id);
  const data = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  const counts = Object.fromEntries(Object.keys(colors).map((k) => [k, 0]));
  for (let i = 0; i < data.length; i += 4) {
    for (const [k, [r, g, b]] of Object.entries(colors)) {
      if (Math.abs(data[i] - r) + Math.abs(data[i + 1] - g) + Math.abs(data[i + 2] - b) < 30
          && data[i + 3] > 200) counts[k] += 1;
    }
  }
  return counts;
}"""

ARM_DIGEST = """() => {
  const c = document.getElementById("arm");
  const data = c.getContext("2d").getImageData(0, 0, c.width, c.height).data;
  let h = 0;
  for (let i = 0; i < data.length; i += 7) h = (h * 31 + data[i]) % 1000000007;
  return h;
}"""


LEGEND_BAND = """(id) => {
  const c = document.getElementById(id);
  const ratio = c.width / c.clientWidth;
  const data = c.getContext("2d").getImageData(0, 0, c.width, Math.floor(22 * ratio)).data;
  const want = {with: [31, 111, 180], without: [154, 154, 154]};
  const counts = {with: 0, without: 0};
  for (let i = 0; i < data.length; i += 4) {
    for (const [k, [r, g, b]] of Object.entries(want)) {
      if (Math.abs(data[i] - r) + Math.abs(data[i + 1] - g) + Math.abs(data[i + 2] - b) < 30
          && data[i + 3] > 200) counts[k] += 1;
    }
  }
  return counts;
}"""
"""Pixels of the sigma legend's colours in the band above the plot frame."""


def colors(page, canvas: str, *names: str) -> dict[str, int]:
    """Pixels of each named colour on a canvas."""
    return page.evaluate(COUNT_COLORS, [canvas, {n: COLORS[n] for n in names}])


def choose_scene(page, server) -> str:
    """The first plan example when the server has one, otherwise a pasted scene."""
    plans = [e for e in httpx.get(server.url + "/v1/examples").json() if e["kind"] == "plan"]
    if plans:
        page.wait_for_function(f"document.getElementById('example').value === {plans[0]['name']!r}")
        return plans[0]["name"]
    page.click("#json-box summary")
    page.fill("#scene-json", json.dumps(CROSSING_SCENE))
    page.click("#apply-json")
    page.click("#json-box summary")
    return "pasted"


# --------------------------------------------------------------------------- tests


def test_plan_an_example_and_watch_it(page, server, tmp_path):
    page.goto(server.url + "/")
    name = choose_scene(page, server)
    scene = (CROSSING_SCENE if name == "pasted"
             else httpx.get(f"{server.url}/v1/examples/{name}").json()["request"])
    assert page.locator("#links tbody tr").count() >= 2
    # before any plan, the arm is drawn at the scene's start
    page.wait_for_timeout(200)
    start = colors(page, "arm", "active", "link")
    assert start["active"] > 100 and start["link"] > 100, start
    page.click("#plan")
    page.wait_for_function("['succeeded', 'failed', 'cancelled']"
                           ".includes(document.getElementById('p-status').textContent)",
                           timeout=PLAN_TIMEOUT)
    job_id = page.get_attribute("#json", "href").rsplit("/", 1)[1]
    job = httpx.get(f"{server.url}/v1/plans/{job_id}").json()
    assert job["status"] == "succeeded", job.get("error")
    plan = job["plan"]

    # progress and summary agree with the API
    assert page.text_content("#p-iteration").startswith(f"{job['progress']['iteration']} / ")
    assert plan["solver"]["status"] in page.text_content("#summary")
    assert plan["verification"]["verified"]
    assert "verifiedyes (tolerance 0.001 rad)" in page.text_content("#summary")
    weights = scene["task"].get("objective", {})
    if weights.get("time", 0) == 0 and weights.get("smoothness", 0) == 0:
        assert " N²m²s (effort " in page.text_content("#summary")  # what the objective is
    crossings = plan["verification"]["waveless_singular_crossings"]
    assert page.locator("#crossings li").count() == len(crossings) + 1

    # the plots: torques, sigma_min with and without waves, crossings marked
    page.wait_for_function("document.getElementById('time').disabled === false")
    page.wait_for_timeout(300)
    sigma = colors(page, "sigma-plot", "with", "without", "mark")
    assert sigma["with"] > 500 and sigma["without"] > 300, sigma
    assert (sigma["mark"] > 25) == bool(crossings), sigma  # dashed, under the legend
    assert sum(colors(page, "torque-plot", "with", "active").values()) > 300
    assert sum(colors(page, "angle-plot", "with", "active").values()) > 300
    labels = {name: page.get_attribute(f"#{name}", "aria-label")
              for name in ("torque-plot", "sigma-plot", "angle-plot")}
    joints = [link["joint"] for link in scene["robot"]["links"]]
    band = page.evaluate(LEGEND_BAND, "sigma-plot")  # the legend sits above the curves
    assert band["with"] > 10 and band["without"] > 10, band
    assert labels == {  # the legends, as the PNG's
        "torque-plot": ", ".join([f"tau{j}" for j, kind in enumerate(joints) if kind == "active"]
                                 + ["over t [s]"]),
        "sigma-plot": "without waves, with waves, over t [s]",
        "angle-plot": ", ".join([f"q{j} ({kind})" for j, kind in enumerate(joints)]
                                + ["over t [s]"])}

    # the arm moves; links, masses and the wavy mass path are drawn
    first = page.evaluate(ARM_DIGEST)
    page.wait_for_timeout(400)
    assert page.evaluate(ARM_DIGEST) != first, "the arm does not animate"
    arm = colors(page, "arm", "active", "link")
    assert arm["active"] > 300 and arm["link"] > 300, arm

    page.click("#play")  # pause at the first waveless crossing, then save the screenshot
    if crossings:
        page.locator("#crossings li").nth(1).click()
        assert page.text_content("#time-label").startswith(f"t = {crossings[0]['time']:.2f} ")
    assert page.page_errors == []
    target = SCREENSHOT if os.environ.get("UNDERTOW_SCREENSHOT") == "1" else tmp_path / "viewer.png"
    page.screenshot(path=str(target), full_page=True)
    assert target.stat().st_size > 50_000

    # an edit marks the plan stale; a refused edit clears it
    assert page.locator("#stale").is_hidden()
    row = page.locator("#links tbody tr.active").first
    index = int(row.locator("td").first.text_content())
    length = float(row.locator(f"[data-loc='robot.links.{index}.length']").input_value())
    row.locator(f"[data-loc='robot.links.{index}.mass']").fill("0.7")
    assert page.locator("#stale").is_visible()
    row.locator(f"[data-loc='robot.links.{index}.wave.amplitude']").fill(str(2 * length))
    page.click("#plan")
    page.wait_for_selector("#error:not([hidden])")
    assert plan["solver"]["status"] not in page.text_content("#summary")
    assert "the edited scene was refused" in page.text_content("#summary")
    assert page.locator("#stale").is_hidden() and page.locator("#downloads").is_hidden()
    assert page.is_disabled("#play")
    assert colors(page, "sigma-plot", "with")["with"] == 0
    assert colors(page, "arm", "link")["link"] > 100  # the edited arm at its start
    assert page.page_errors == []


def test_field_errors_are_shown_at_the_field(page, server):
    page.goto(server.url + "/")
    choose_scene(page, server)
    row = page.locator("#links tbody tr.active").first
    index = int(row.locator("td").first.text_content())
    length = float(row.locator(f"[data-loc='robot.links.{index}.length']").input_value())
    row.locator(f"[data-loc='robot.links.{index}.wave.amplitude']").fill(str(2 * length))
    page.click("#plan")
    page.wait_for_selector("#error:not([hidden])")
    text = page.text_content("#error")
    assert "The scene was refused: The request is not valid (422)" in text
    assert f"robot.links.{index}.wave.amplitude must be smaller than the link length" in text
    amplitude = page.locator(f"[data-loc='robot.links.{index}.wave.amplitude']")
    assert "invalid" in amplitude.get_attribute("class")
    assert page.page_errors == []


def test_a_server_with_an_api_key_asks_for_it(page, tmp_path):
    with LiveServer(tmp_path / "jobs.sqlite3", UNDERTOW_API_KEY="s3cret") as keyed:
        page.goto(keyed.url + "/")
        page.wait_for_selector("#key-form:not([hidden])")
        assert "Missing or wrong API key (401)" in page.text_content("#error")
        page.fill("#api-key", "s3cret")
        page.click("#key-form button")
        page.wait_for_selector("#error", state="hidden")
        assert page.locator("#example option").count() >= 1
        assert page.evaluate("localStorage.getItem('undertow.apiKey')") == "s3cret"
        assert page.page_errors == []
