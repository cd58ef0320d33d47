"""The session dashboard (static/, served at "/"): its files over HTTP, and the page itself in
a real headless Chromium against a real server with a streamed scene."""

from __future__ import annotations

import asyncio
import io
import re
import shutil
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import httpx
import pytest
from analytic_world import Rect
from browser_pages import checked_page
from devices import frame_message, stream_in_step
from living_world import AFTER, BEFORE, KNOBS, WALK_2_T, walk
from relation_scene import SCENE as RELATION_SCENE
from relation_scene import scene_export
from spoken import ASR_TIMEOUT_S, fake_microphone_args, speak

from app.server.routes.pages import STATIC_DIR

try:  # a QR decoder (a dev dependency): without it only the QR code's reading is skipped
    import zxingcpp
    from PIL import Image
except ImportError:
    zxingcpp = None

try:  # optional: without playwright only the browser tests skip
    from playwright.sync_api import expect, sync_playwright
except ImportError:
    expect = sync_playwright = None

ARTIFACTS = Path(__file__).resolve().parents[3] / "out" / "test-artifacts"
VIEWPORT = {"width": 1280, "height": 900}
CHROMIUM_ARGS = [
    "--no-sandbox",  # tests may run as root in a container, where the sandbox cannot start
    "--disable-gpu",
    "--disable-background-networking",  # no internet here: no update checks, no telemetry
    "--disable-component-update",
    "--no-first-run",
]

CHAIR = Rect(1, "chair", -0.6, -0.3, -0.1, 0.3, 2.0)
FRIDGE = Rect(2, "refrigerator", 0.1, -0.8, 0.9, 0.8, 2.5)
SCENE = [CHAIR, FRIDGE]
FAST = {  # confirm objects after two keyframes, so three frames make a map
    "keyframe_interval": 1,
    "min_observations": 2,
    "min_mapping_bbox_area": 100,
    "local_map_update_frequency": 1,
}


def chromium_path() -> str | None:
    """Debian's chromium (Playwright's own download needs internet)."""
    for name in ("chromium", "chromium-headless-shell", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def dashboard_playwright():
    """This module's one Playwright (a second on the same thread fails while one runs): every
    browser here is launched from it."""
    if sync_playwright is None:
        pytest.skip("playwright is not installed (pip install -e '.[dev]')")
    if chromium_path() is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    with sync_playwright() as playwright:
        yield playwright


@contextmanager
def launched(playwright, extra_args: Sequence[str] = ()) -> Iterator:
    """A headless Chromium with CHROMIUM_ARGS and `extra_args`, closed after."""
    args = [*CHROMIUM_ARGS, *extra_args]
    browser = playwright.chromium.launch(executable_path=chromium_path(), args=args)
    try:
        yield browser
    finally:
        browser.close()


@pytest.fixture(scope="module")
def browser(dashboard_playwright):
    with launched(dashboard_playwright) as browser:
        yield browser


@pytest.fixture
def page(browser):
    yield from checked_page(browser, VIEWPORT)


def screenshot(page, name: str) -> None:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(ARTIFACTS / name), full_page=True)


def map_the_scene(server, headers=None) -> str:
    """A session holding a chair and a refrigerator; its id."""
    with httpx.Client(base_url=server.url, headers=headers) as c:
        r = c.post("/v1/sessions", json={"name": "kitchen", "knobs": FAST})
        assert r.status_code == 201, r.text
        created = r.json()
    sid = created["session_id"]
    frames = [frame_message(SCENE, i, cam_xy=(0.03 * i, 0.0)) for i in range(3)]
    token = {"Authorization": f"Bearer {created['token']}"}
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    # Playwright's sync API keeps an event loop running on this thread: stream on another.
    with ThreadPoolExecutor(1) as pool:
        replies = pool.submit(asyncio.run, stream_in_step(url, frames, token)).result()
    assert [r["type"] for r in replies] == ["ack"] * 3
    return sid


# --- the files ---------------------------------------------------------------------------


def test_the_server_serves_the_dashboard_and_its_assets(live_server):
    server = live_server()
    with httpx.Client(base_url=server.url) as c:
        index = c.get("/")
        assert index.status_code == 200
        assert index.headers["content-type"].startswith("text/html")
        assert "/static/app.js" in index.text and "/static/style.css" in index.text
        assert "default-src 'self'" in index.headers["content-security-policy"]
        script = c.get("/static/app.js")
        assert script.status_code == 200
        assert script.headers["content-type"].startswith("text/javascript")
        assert c.get("/static/style.css").headers["content-type"].startswith("text/css")
        assert c.get("/static/nope.js").status_code == 404
        assert c.get("/static/%2e%2e/pyproject.toml").status_code == 404
        assert "/" not in c.get("/openapi.json").json()["paths"]  # not part of protocol v1


def _without_comments(path: Path) -> str:
    text = path.read_text()
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)  # HTML
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)  # CSS and JS block comments
    return re.sub(r"(?m)^\s*//.*$", "", text)  # JS line comments


def test_the_pages_load_nothing_from_outside_the_server():
    files = sorted(p for p in STATIC_DIR.iterdir() if p.suffix in (".html", ".js", ".mjs", ".css"))
    assert {p.name for p in files} >= {"index.html", "app.js", "session-qr.mjs", "style.css"}
    for path in files:
        # absolute URLs, and protocol-relative ones starting a string or url(...)
        found = re.findall(r"https?://\S*|[\"'(]//\S*", _without_comments(path))
        assert not found, f"{path.name} references {found}"


def test_the_qr_module_loads_only_the_vendored_generator():
    code = _without_comments(STATIC_DIR / "session-qr.mjs")
    imports = re.findall(r"^import .* from \"(.*)\";", code, flags=re.M)
    assert imports == ["./vendor/qrcode-generator@2.0.4/dist/qrcode.mjs"]
    assert (STATIC_DIR / "vendor" / "qrcode-generator@2.0.4" / "dist" / "qrcode.mjs").is_file()
    # Besides the QR module, app.js imports only the modules it shares with the /xr page.
    assert re.findall(
        r"^import .* from \"(.*)\";", _without_comments(STATIC_DIR / "app.js"), re.M
    ) == [
        "./common/auth.mjs",
        "./common/push-to-talk.mjs",
        "./common/recorder.mjs",
        "./common/words.mjs",
        "./session-qr.mjs",
    ]
    for shared in ("auth.mjs", "push-to-talk.mjs", "recorder.mjs", "words.mjs"):
        assert not re.findall(r"^import ", _without_comments(STATIC_DIR / "common" / shared), re.M)


def test_the_script_never_writes_html():
    # Labels and names are user data: only textContent reaches the page.
    code = _without_comments(STATIC_DIR / "app.js")
    for sink in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval("):
        assert sink not in code


# --- the page in a browser ---------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_dashboard_lists_a_session_and_answers_a_query(live_server, page):
    server = live_server()
    sid = map_the_scene(server)
    page.goto(f"{server.url}/?viewer=http://127.0.0.1:9999/")

    card = page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".session-name")).to_have_text("kitchen")
    expect(card.locator(".stat-objects")).to_have_text("2")
    expect(card.locator(".stat-frames")).to_have_text("3 · 3")
    expect(card.locator(".stat-apart")).to_have_text("3 · 0")  # whole frames, no sightings
    expect(page.locator("#status")).to_have_attribute("data-state", "live")
    expect(page.locator("#viewer-link")).to_have_attribute("href", "http://127.0.0.1:9999/")
    screenshot(page, "dashboard_session.png")

    card.locator(".query-input").fill("where do I keep milk cold")
    card.locator(".query-button").click()
    first_row = card.locator(".results tbody tr").first
    expect(first_row.locator("td.label")).to_have_text("refrigerator")
    expect(card.locator(".results tbody tr")).to_have_count(2)  # k=5, two objects in the map
    expect(card.locator(".query-meta")).to_contain_text("2 results")
    expect(card.locator(".query-meta")).not_to_contain_text("no confident match")
    expect(first_row).not_to_have_class(re.compile(r"\bweak\b"))
    screenshot(page, "dashboard_query.png")

    card.locator(".query-input").fill("xyzzy plugh")
    card.locator(".query-button").click()
    expect(card.locator(".query-meta")).to_contain_text("no confident match")
    expect(card.locator(".results tbody tr.weak")).to_have_count(2)  # listed, but weak


LABEL_BOXES_JS = """card => [...card.querySelectorAll('.plot-label')].map(el => {
    const r = el.getBoundingClientRect();
    return {text: el.textContent, left: r.left, top: r.top, right: r.right, bottom: r.bottom};
})"""


def crowded_answer(route) -> None:
    """Five hits with long labels whose centroids are a few centimetres apart, as the
    server's query answer: the plot must still lay their labels out without overlap."""
    hits = [
        {
            "id": 10 + i,
            "label": f"kitchen cabinet number {i}",
            "score": 0.6 - 0.01 * i,
            "relevance": 0.9 - 0.1 * i,
            "centroid": [0.3 + 0.02 * i, 0.1 + 0.03 * i, 1.0],
            "bbox": [0.2 + 0.02 * i, 0.0, 0.0, 0.4 + 0.02 * i, 0.2 + 0.03 * i, 2.0],
        }
        for i in range(5)
    ]
    body = {"text": "cabinets", "results": hits, "latency_ms": 1.0, "match": True}
    route.fulfill(json=body)


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_plot_lays_the_hits_labels_out_without_overlap(live_server, page):
    server = live_server()
    sid = map_the_scene(server)
    page.route(re.compile(r"/v1/sessions/[^/]+/query\?"), crowded_answer)
    page.goto(server.url)
    card = page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".stat-objects")).to_have_text("2")
    card.locator(".query-input").fill("cabinets")
    card.locator(".query-button").click()
    expect(card.locator(".results tbody tr")).to_have_count(5)
    labels = card.locator(".plot-label")
    expect(labels.first).to_be_visible()
    boxes = card.evaluate(LABEL_BOXES_JS)
    canvas = card.locator(".plot-canvas").bounding_box()
    screenshot(page, "dashboard_crowded_labels.png")
    # the best hit is always labelled in full; the others as room allows (at least the rank)
    assert boxes[0]["text"] == "1 kitchen cabinet number 0"
    assert len(boxes) >= 3
    for box in boxes:
        assert box["left"] >= canvas["x"] and box["right"] <= canvas["x"] + canvas["width"]
        assert box["top"] >= canvas["y"] and box["bottom"] <= canvas["y"] + canvas["height"]
    for a_index, a in enumerate(boxes):
        for b in boxes[a_index + 1 :]:
            apart = (
                a["right"] <= b["left"]
                or b["right"] <= a["left"]
                or a["bottom"] <= b["top"]
                or b["bottom"] <= a["top"]
            )
            assert apart, f"labels overlap: {a} and {b}"


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_with_an_api_key_the_page_asks_for_it_and_shows_names_as_text(live_server, page):
    server = live_server(api_key="sesame")
    key = {"Authorization": "Bearer sesame"}
    hostile = "<img src=x onerror=\"document.title='pwned'\">"
    with httpx.Client(base_url=server.url, headers=key) as c:
        created = c.post("/v1/sessions", json={"name": hostile, "knobs": FAST}).json()
    sid = created["session_id"]
    page.goto(server.url)

    # Without the key the list is refused, and the page says why (status and detail).
    expect(page.locator("#banner")).to_contain_text("HTTP 401: missing API key")
    expect(page.locator("#access")).to_have_attribute("open", "")

    # A session's own token shows that session alone.
    page.locator("#token-sid").fill(sid)
    page.locator("#token-value").fill(created["token"])
    page.locator("#token-form button[type=submit]").click()
    card = page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".session-name")).to_have_text(hostile)
    expect(card.locator(".session-name img")).to_have_count(0)

    # A wrong token for another session: its card shows the server's refusal.
    page.locator("#token-sid").fill("not-a-session")
    page.locator("#token-value").fill("wrong")
    page.locator("#token-form button[type=submit]").click()
    expect(page.locator('article[data-sid="not-a-session"] .card-error')).to_have_text(
        "HTTP 403: wrong token for this session"
    )

    # The key lists everything.
    page.locator("#api-key").fill("sesame")
    page.locator("#key-form button[type=submit]").click()
    expect(page.locator("#banner")).to_be_hidden()
    expect(page.locator("#status")).to_have_attribute("data-state", "live")
    screenshot(page, "dashboard_api_key.png")
    assert page.title() != "pwned"


@pytest.mark.timeout(120)
def test_the_api_docs_render_offline_and_offer_authorize(live_server, page):
    server = live_server(api_key="sesame")
    elsewhere: list[str] = []

    def only_this_server(route) -> None:  # no network: anything not ours fails
        if route.request.url.startswith(server.url):
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort()

    page.route("**/*", only_this_server)
    page.goto(f"{server.url}/docs")
    operations = page.locator(".opblock")
    expect(operations.first).to_be_visible()
    expect(
        # the text query exactly (its spoken sibling, .../query/speech, is another operation)
        page.locator(".opblock-summary-path", has_text=re.compile(r"/query$")).filter(
            has_text="/v1/sessions/{sid}/"
        )
    ).to_have_count(1)
    assert operations.count() >= 8
    page.locator(".auth-wrapper .authorize").click()
    dialog = page.locator(".dialog-ux .modal-ux")
    expect(dialog).to_contain_text("apiKey")
    expect(dialog).to_contain_text("sessionToken")
    # Authorize with the API key, then list sessions from the page: the key goes along.
    dialog.locator("input").first.fill("sesame")
    dialog.locator("button.authorize").first.click()
    dialog.locator("button.close-modal").click()
    listing = page.locator(".opblock-get", has=page.locator('[data-path="/v1/sessions"]'))
    listing.locator(".opblock-summary").click()
    listing.locator(".try-out__btn").click()
    listing.locator(".execute").click()
    expect(listing.locator(".live-responses-table tbody .response-col_status")).to_have_text("200")
    screenshot(page, "api_docs.png")
    assert not elsewhere, f"/docs reached outside the server: {elsewhere}"


# --- the living map on the page ----------------------------------------------------------

DINING_TABLE = Rect(6, "dining table", 0.2, 0.52, 1.1, 0.85, 2.0)
"""Under the mug's new place in test_living_map's room (the cameras' up is -y there)."""


def change_the_room(server) -> str:
    """test_living_map's two walks with a dining table: the mug moves onto it, the book is
    taken away, a cardboard box and a potted plant appear. The session's id."""
    sid = httpx.post(f"{server.url}/v1/sessions", json={"name": "living room", "knobs": KNOBS})
    sid = sid.json()["session_id"]
    url = f"{server.ws_url}/v1/sessions/{sid}/stream"
    walks = [walk([*BEFORE, DINING_TABLE], 0.0), walk([*AFTER, DINING_TABLE], WALK_2_T)]
    with ThreadPoolExecutor(1) as pool:  # off Playwright's event loop, as map_the_scene
        for frames in walks:
            acks = pool.submit(asyncio.run, stream_in_step(url, frames)).result()
            assert all(a["type"] == "ack" for a in acks), acks
    return sid


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_dashboard_tells_what_changed_where_and_when(live_server, page):
    server = live_server()
    sid = change_the_room(server)
    page.goto(server.url)
    card = page.locator(f'article[data-sid="{sid}"]')
    lines = card.locator(".changes-list li")
    expect(lines).to_have_count(4)
    ago = r" · (just now|\d s ago)$"
    expect(lines.filter(has_text="mug")).to_have_text(
        re.compile(r"^mug moved on the dining table" + ago)
    )
    expect(lines.filter(has_text="book")).to_have_text(
        re.compile(r"^book removed from near the cardboard box" + ago)
    )
    expect(lines.filter(has_text="cardboard box added")).to_have_text(
        re.compile(r"^cardboard box added near the dining table" + ago)
    )
    expect(lines.filter(has_text="potted plant")).to_have_text(
        re.compile(r"^potted plant added near the \w[\w ]*" + ago)
    )
    screenshot(page, "dashboard_changes.png")

    # the removed book answers only with "include removed", saying where and when it was
    card.locator(".query-input").fill("where did I leave my book")
    card.locator(".query-button").click()
    expect(card.locator(".query-meta")).to_contain_text("results")
    expect(card.locator(".results tbody tr.removed")).to_have_count(0)
    card.locator(".query-removed").check()
    card.locator(".query-button").click()
    first = card.locator(".results tbody tr").first
    expect(first.locator("td.label")).to_have_text("book")
    expect(first).to_have_class(re.compile(r"\bremoved\b"))
    expect(first.locator("td.seen")).to_have_text(
        re.compile(r"^\(removed\) · near the cardboard box · last seen 10 min ago$")
    )
    # the answer in words: where it was last seen, and when
    expect(card.locator(".query-answer")).to_have_text("book — near the cardboard box, 10 min ago")
    screenshot(page, "dashboard_removed_hit.png")

    # a thing that moved: the place is the object it rests on
    card.locator(".query-input").fill("where did I leave my mug")
    card.locator(".query-button").click()
    expect(card.locator(".query-answer")).to_have_text(
        re.compile(r"^mug — on the dining table, (just now|\d+ s ago)$")
    )


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_against_a_server_without_the_living_map_the_page_leaves_it_out(live_server, page):
    server = live_server()
    sid = map_the_scene(server)
    page.route(
        re.compile(r"/v1/sessions/[^/]+/changes\?"),
        lambda route: route.fulfill(status=404, json={"detail": "Not Found"}),
    )
    page.route(re.compile(r"/v1/sessions/[^/]+/query\?"), crowded_answer)  # no times, no state
    changes_asked = re.compile(r"/v1/sessions/[^/]+/changes\?")
    with page.expect_request(changes_asked):
        page.goto(server.url)
    with page.expect_request(changes_asked):  # the next poll: the first 404 was handled
        pass
    card = page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".stat-objects")).to_have_text("2")
    card.locator(".query-input").fill("cabinets")
    card.locator(".query-button").click()
    expect(card.locator(".results tbody tr")).to_have_count(5)
    expect(card.locator(".results td.seen").first).to_have_text("")
    expect(card.locator(".changes")).to_be_hidden()
    expect(card.locator(".card-error")).to_be_hidden()


# --- relational answers on the page ------------------------------------------------------


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_the_dashboard_says_a_relational_answer_in_words_and_plots_its_anchor(live_server, page):
    server = live_server()
    created = httpx.post(
        f"{server.url}/v1/sessions/import", json=scene_export("office"), timeout=30
    )
    assert created.status_code == 201, created.text
    sid = created.json()["session_id"]
    page.goto(server.url)
    card = page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".stat-objects")).to_have_text(str(len(RELATION_SCENE)))

    card.locator(".query-input").fill("the mug on the desk")
    card.locator(".query-button").click()
    expect(card.locator(".query-answer")).to_have_text("mug — on the desk")
    rows = card.locator(".results tbody tr")
    expect(rows.first.locator("td.label")).to_have_text("mug — on the desk")
    expect(rows.first.locator("td.num").nth(1)).to_have_text("10")  # the mug on desk 1
    expect(rows.nth(1).locator("td.label")).to_have_text("mug — not on the desk")
    expect(rows.nth(1)).to_have_class(re.compile(r"\bweak\b"))  # a mug, but not that one
    expect(card.locator(".plot-label.anchor")).to_have_text("desk")
    screenshot(page, "dashboard_relation.png")

    card.locator(".query-input").fill("the mug under the sofa")  # no mug is
    card.locator(".query-button").click()
    expect(card.locator(".query-meta")).to_contain_text("no confident match")
    expect(card.locator(".query-answer")).to_be_hidden()
    expect(rows.first.locator("td.label")).to_have_text("mug — not under the sofa")

    card.locator(".query-input").fill("where is the sofa")  # a plain question: no anchor left
    card.locator(".query-button").click()
    expect(rows.first.locator("td.label")).to_have_text("sofa")
    expect(card.locator(".plot-label.anchor")).to_have_count(0)


# --- the session's page for a phone --------------------------------------------------------


def read_qr(locator) -> list[str]:
    """What the QR code shown by `locator` (an element) says, read from a screenshot."""
    if zxingcpp is None:
        pytest.skip("zxing-cpp is not installed (pip install -e '.[dev]')")
    picture = Image.open(io.BytesIO(locator.screenshot())).convert("L")
    return [barcode.text for barcode in zxingcpp.read_barcodes(picture)]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_each_card_shows_a_qr_code_of_its_phone_page_with_the_token_in_the_fragment_only(
    live_server, page
):
    server = live_server(api_key="sesame")
    key = {"Authorization": "Bearer sesame"}
    created = httpx.post(f"{server.url}/v1/sessions", json={"name": "hall"}, headers=key).json()
    sid, token = created["session_id"], created["token"]
    requested: list[str] = []
    page.on("request", lambda request: requested.append(request.url))
    page.goto(server.url)

    # The API key alone lists the session: its code opens the page without any credential.
    page.locator("#api-key").fill("sesame")
    page.locator("#key-form button[type=submit]").click()
    card = page.locator(f'article[data-sid="{sid}"]')
    qr = card.locator(".phone-qr")
    expect(qr).to_have_attribute("src", re.compile(r"^data:image/gif;base64,"))
    bare = f"{server.url}/xr#session={sid}"
    expect(card.locator(".phone-link")).to_have_attribute("href", bare)
    assert read_qr(qr) == [bare]
    expect(card.locator(".phone-token")).to_contain_text("No token in it")

    # With the session's own token held, the code carries it, in the fragment only.
    page.locator("#token-sid").fill(sid)
    page.locator("#token-value").fill(token)
    page.locator("#token-form button[type=submit]").click()
    with_token = f"{bare}&token={token}"
    expect(card.locator(".phone-link")).to_have_attribute("href", with_token)
    screenshot(page, "dashboard_phone_qr.png")
    (scanned,) = read_qr(qr)
    assert scanned == with_token
    parts = urlsplit(scanned)
    assert (parts.path, parts.query) == ("/xr", "")
    assert parse_qs(parts.fragment) == {"session": [sid], "token": [token]}
    assert "sesame" not in scanned  # never the API key

    assert all(url.startswith((server.url, "data:")) for url in requested), requested
    assert not any(token in url for url in requested)  # a fragment never leaves the page


# --- asking aloud: the mic button with a fake microphone ---------------------------------

SPOKEN = "where is the refrigerator"
SPEAKING_MS = 2500
"""How long the person talks: the synthesised question lasts about 1.5 s, silence after."""


@pytest.fixture(scope="module")
def mic_browser(dashboard_playwright, tmp_path_factory):
    """A Chromium whose microphone says SPOKEN at the start of every recording."""
    wav = speak(SPOKEN, tmp_path_factory.mktemp("speech") / "question.wav")
    with launched(dashboard_playwright, fake_microphone_args(wav)) as browser:
        yield browser


@pytest.fixture
def mic_page(mic_browser):
    yield from checked_page(mic_browser, VIEWPORT)


def speech_requests(page) -> list:
    """The page's POSTs to the speech endpoint, as Playwright sees them leave."""
    sent: list = []
    page.on("request", lambda r: sent.append(r) if "/query/speech" in r.url else None)
    return sent


def ask_aloud_with_taps(page, card) -> None:
    """Tap the card's mic button, talk, tap it again."""
    mic = card.locator(".query-mic")
    expect(mic).to_be_enabled()
    mic.click()
    expect(mic).to_have_attribute("data-state", "listening")
    page.wait_for_timeout(SPEAKING_MS)  # the person talking: not a wait on the page
    mic.click()


def result_rows(card) -> list[str]:
    return card.locator(".results tbody tr").all_inner_texts()


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_mic_button_asks_aloud_and_shows_the_answer_as_a_typed_ones(live_server, mic_page):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    sid = map_the_scene(server)
    sent = speech_requests(mic_page)
    mic_page.goto(server.url)
    card = mic_page.locator(f'article[data-sid="{sid}"]')
    expect(card.locator(".stat-objects")).to_have_text("2")

    ask_aloud_with_taps(mic_page, card)
    heard = card.locator(".query-heard")
    expect(heard).to_contain_text("recognised on the server (offline)")
    expect(card.locator(".query-mic")).to_have_attribute("data-state", "idle")
    (request,) = sent
    assert request.method == "POST"
    headers = request.all_headers()  # a Blob body is in neither post_data nor sizes()
    assert headers["content-type"].startswith("audio/webm")  # Chromium's Opus in WebM
    assert int(headers["content-length"]) > 2000  # 2.5 s of Opus
    assert parse_qs(urlsplit(request.url).query) == {"k": ["5"], "points": ["false"]}
    transcript = card.locator(".query-input").input_value()
    assert transcript and f"heard “{transcript}”" in heard.inner_text()
    assert "refrigerator" in transcript
    spoken_rows = result_rows(card)
    assert spoken_rows[0].split("\t")[2] == "refrigerator"
    screenshot(mic_page, "dashboard_spoken_query.png")

    # The same words typed get the same answer, shown the same way.
    meta = card.locator(".query-meta")
    spoken_meta = meta.inner_text()
    card.locator(".query-button").click()
    expect(meta).not_to_have_text("asking…")
    assert meta.inner_text().rsplit(" in ", 1)[0] == spoken_meta.rsplit(" in ", 1)[0]  # not latency
    assert result_rows(card) == spoken_rows
    expect(heard).to_be_hidden()


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_the_dashboard_shows_the_servers_words_for_audio_it_refuses(live_server, mic_page):
    server = live_server(asr_timeout_s=ASR_TIMEOUT_S)
    sid = map_the_scene(server)
    # The recording garbled on its way: the server cannot decode it.
    mic_page.route("**/query/speech?*", lambda route: route.continue_(post_data=b"not audio"))
    mic_page.goto(server.url)
    card = mic_page.locator(f'article[data-sid="{sid}"]')
    ask_aloud_with_taps(mic_page, card)
    meta = card.locator(".query-meta")
    expect(meta).to_contain_text("HTTP 400")
    expect(meta).to_have_class(re.compile(r"\berror\b"))
    expect(card.locator(".query-heard")).to_be_hidden()
    expect(card.locator(".results")).to_be_hidden()
