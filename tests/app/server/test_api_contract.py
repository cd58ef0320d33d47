"""The REST contract as /openapi.json states it, checked from outside: the links from a new
session to the operations on it, the security each operation declares, and a bounded
schemathesis run (coverage, fuzzing and stateful phases) against a real server."""

from __future__ import annotations

import collections
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

from app.semantics import DEFAULT_MODEL_ID
from app.semantics.static import StaticTower
from app.server.app import create_app
from app.server.settings import ServerSettings

API_KEY = "contract-test-key"
SCHEMATHESIS_CONFIG = Path(__file__).with_name("schemathesis.toml")
REPO = Path(__file__).parents[3]
"""Where schemathesis runs: the config names its hooks file from there."""
SESSION_PATH = "/v1/sessions/{sid}"
PUBLIC_PATHS = ("/v1/text-towers/", "/v1/answering/")
"""Operations that need no credential: a static text tower by its hash."""
CREATING = (("/v1/sessions", "post"), ("/v1/sessions/import", "post"))
"""The operations whose 201 answer is a new session (SessionCreated)."""


@pytest.fixture(scope="module")
def document(tmp_path_factory) -> dict:
    """The OpenAPI document, as GET /openapi.json serves it (no server needed)."""
    settings = ServerSettings(data_dir=str(tmp_path_factory.mktemp("data")), api_key=API_KEY)
    return create_app(settings).openapi()


def operations(document: dict):
    for path, methods in document["paths"].items():
        for method, operation in methods.items():
            yield path, method, operation


def linkable(path: str) -> bool:
    """An operation on a session that a link from a new session can reach: its only path
    parameter is the session id (an object's history needs an object id no new session has;
    tests/app/server/test_living_map.py calls it)."""
    return path.startswith(SESSION_PATH) and re.findall(r"{(\w+)}", path) == ["sid"]


def evaluate(expression: str, body: dict) -> str:
    """An OpenAPI runtime expression over a response body: `$response.body#/field`, alone
    or embedded in a string as `{$response.body#/field}`."""
    whole = re.fullmatch(r"\$response\.body#/(\w+)", expression)
    if whole:
        return body[whole.group(1)]
    return re.sub(r"\{\$response\.body#/(\w+)\}", lambda m: body[m.group(1)], expression)


def test_a_new_session_links_to_every_operation_on_it(document):
    on_session = {op["operationId"] for path, _, op in operations(document) if linkable(path)}
    assert len(on_session) >= 7  # get, delete, knobs get and patch, objects, query, export
    for path, method in CREATING:
        links = document["paths"][path][method]["responses"]["201"]["links"]
        assert {link["operationId"] for link in links.values()} == on_session, path
        for link in links.values():
            assert link["parameters"] == {
                "sid": "$response.body#/session_id",
                "header.Authorization": "Bearer {$response.body#/token}",
            }


def test_every_operation_declares_the_credential_it_needs(document):
    schemes = document["components"]["securitySchemes"]
    assert schemes["apiKey"] == schemes["apiKey"] | {"type": "http", "scheme": "bearer"}
    assert schemes["sessionToken"] == schemes["sessionToken"] | {"type": "http", "scheme": "bearer"}
    for path, method, operation in operations(document):
        if path.startswith(SESSION_PATH):
            expected = [{"sessionToken": []}, {"apiKey": []}]  # the API key opens any session
        elif path == "/healthz":
            expected = None
        elif path.startswith(PUBLIC_PATHS):
            expected = []  # content-addressed, no user data: no credential
        else:
            expected = [{"apiKey": []}]
        assert operation.get("security") == expected, (method, path)
        if expected:  # and each says what it answers without it
            assert {"401", "403"} <= operation["responses"].keys(), (method, path)


def test_following_a_link_with_the_session_token_alone_reaches_the_session(live_server):
    server = live_server(api_key=API_KEY)
    with httpx.Client(base_url=server.url, timeout=30) as http:
        created = http.post(
            "/v1/sessions", json={}, headers={"Authorization": f"Bearer {API_KEY}"}
        ).json()
        document = http.get("/openapi.json").json()
        by_id = {op["operationId"]: (method, path) for path, method, op in operations(document)}
        links = document["paths"]["/v1/sessions"]["post"]["responses"]["201"]["links"]
        # the session's own calls first, its deletion last
        for name in sorted(links, key=lambda name: name.startswith("delete")):
            link = links[name]
            method, path = by_id[link["operationId"]]
            values = {key: evaluate(expr, created) for key, expr in link["parameters"].items()}
            answer = http.request(
                method.upper(),
                path.replace("{sid}", values["sid"]),
                params={"text": "chair"},  # the one required query parameter (query)
                headers={"Authorization": values["header.Authorization"]},
                json={"min_observations": 3} if method == "patch" else None,
            )
            if path.endswith("/query/speech"):  # needs speech: past the credentials is reached
                assert answer.status_code == 415, (name, answer.status_code, answer.text)
                continue
            assert answer.is_success, (name, answer.status_code, answer.text)


def test_allow_lists_what_the_document_says_a_literal_path_takes(live_server):
    server = live_server()
    answer = httpx.request("OPTIONS", f"{server.url}/v1/sessions/import")
    assert answer.status_code == 405
    assert answer.headers["allow"] == "POST"  # not the GET and DELETE of /v1/sessions/{sid}


# ------------------------------------------------------------------------ schemathesis
def run_figures(ndjson: Path) -> dict:
    """From schemathesis' NDJSON report: per phase, the test cases generated, the seconds it
    took, and the status codes each operation answered."""
    cases: collections.Counter = collections.Counter()
    seconds: dict[str, float] = collections.defaultdict(float)
    started: dict[str, float] = {}
    answers: dict = collections.defaultdict(collections.Counter)
    with ndjson.open() as events:
        for line in events:
            (kind, event), *_ = json.loads(line).items()
            if kind == "PhaseStarted":
                started[event["phase"]["name"]] = event["timestamp"]
            elif kind == "PhaseFinished" and event["phase"]["name"] in started:
                name = event["phase"]["name"]
                seconds[name] += event["timestamp"] - started.pop(name)
            elif kind == "ScenarioFinished":
                recorder = event["recorder"]
                cases[event["phase"]] += len(recorder.get("cases", {}))
                for case_id, interaction in recorder.get("interactions", {}).items():
                    case = recorder["cases"][case_id]["value"]
                    status = (interaction.get("response") or {}).get("status_code")
                    answers[event["phase"], case["method"], case["path"]][status] += 1
    return {"cases": cases, "seconds": seconds, "answers": answers}


@pytest.mark.slow
@pytest.mark.timeout(360)
def test_the_api_keeps_its_contract_under_schemathesis(live_server, tmp_path):
    """Every check but positive_data_acceptance (see schemathesis.toml): no 5xx but a 503
    with Retry-After, every status, content type, header and body as documented, bad input
    refused, auth not ignored, a deleted session gone. The API key goes to the calls that take it; the operations on a
    session are reached through the links of a new session, with its own token."""
    # Each case that creates a session keeps it: far more than the default cap of 64. Static
    # sessions get a tiny random tower (without one the first would wait minutes for the
    # server to distil its own).
    tower = tmp_path / "tiny.tower"
    rows = np.random.default_rng(0).normal(size=(4, 8))
    tower.write_bytes(
        StaticTower.build(["[UNK]", "a", "chair", "##s"], rows, teacher=DEFAULT_MODEL_ID).to_bytes()
    )
    server = live_server(api_key=API_KEY, max_sessions=10_000, static_tower=str(tower))
    reports = tmp_path / "schemathesis"
    run = subprocess.run(
        [
            *(sys.executable, "-m", "schemathesis.cli"),
            *("--config-file", str(SCHEMATHESIS_CONFIG), "run", f"{server.url}/openapi.json"),
            *("--no-color", "--report", "json,ndjson", "--report-dir", str(reports)),
        ],
        env=dict(os.environ, SEMANTICXR_API_KEY=API_KEY),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    output = run.stdout[-8000:] + run.stderr[-2000:]
    json_reports, ndjson_reports = sorted(reports.glob("json-*")), sorted(reports.glob("ndjson-*"))
    assert json_reports and ndjson_reports, f"schemathesis wrote no report:\n{output}"
    report = json.loads(json_reports[0].read_text())
    figures = run_figures(ndjson_reports[0])
    print(
        f"schemathesis {report['schemathesis_version']} seed {report['seed']}: "
        f"{report['test_cases']['generated']} cases in {report['running_time']:.0f} s; "
        + ", ".join(
            f"{phase} {figures['cases'][phase]} cases {figures['seconds'][phase]:.0f} s"
            for phase in ("examples", "coverage", "fuzzing", "stateful")
        )
        + f"; {report['test_cases']['unique_failures']} failures"
    )
    assert run.returncode == 0, output
    for phase in ("coverage", "fuzzing", "stateful"):
        assert report["phases"][phase]["status"] == "success", (phase, report["phases"])
    answered = figures["answers"]
    for path, method, _ in operations(server.app.openapi()):
        # reached with a token only a link could carry; generated bytes are never speech
        if linkable(path) and not path.endswith("/query/speech"):
            codes = answered["stateful", method.upper(), path]
            assert any(200 <= code < 300 for code in codes), (method, path, dict(codes))
