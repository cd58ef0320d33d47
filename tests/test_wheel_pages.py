"""The built wheel serves the pages whole: a server run from the wheel's files (not the
checkout) answers /xr and every module the pages import, as JavaScript, under the same CSP;
and it holds the top-level packages beside app/ (the synthetic world, the evaluation) and
the match rule's data files."""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import httpx
import pytest

from app.server.runner import ServerProcess

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def imports_of(source: str) -> list[str]:
    """The relative module paths an ES module imports (static and `new URL(...)` workers)."""
    found = re.findall(r"""(?:from|import)\s*\(?\s*["'](\.{1,2}/[^"']+)["']""", source)
    found += re.findall(r"""new URL\(\s*["'](\.{1,2}/[^"']+)["']""", source)
    return found


def test_a_server_installed_from_the_wheel_serves_the_real_device_page_whole(tmp_path, monkeypatch):
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w"]
        + [str(tmp_path / "dist"), str(ROOT)],
        check=True,
        capture_output=True,
    )
    (wheel,) = (tmp_path / "dist").glob("semanticxr-*.whl")
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    # The wheel's own app/ and static/, never the checkout's: its folder first, run elsewhere.
    monkeypatch.setenv("PYTHONPATH", str(site))
    monkeypatch.chdir(tmp_path)
    where = subprocess.run(
        [sys.executable, "-c", "import app.server.routes.pages as p; print(p.STATIC_DIR)"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    assert Path(where) == site / "static"
    # The top-level packages beside app/: the synthetic world and the evaluation.
    names = set(zipfile.ZipFile(wheel).namelist())
    for module in ("world/__init__.py", "world/render.py", "evaluation/__init__.py"):
        assert module in names, module
    assert "evaluation/walk.py" in names and "evaluation/relations.py" in names
    # The match rule's data: the rule, the background texts and their shipped embeddings.
    for data in ("match_rules.json", "background_texts.json"):
        assert f"app/answering/{data}" in names, data
    assert any(n.startswith("app/answering/background_embeddings/") for n in names)
    found = subprocess.run(
        [
            sys.executable,
            "-c",
            "import evaluation.revisit as e, world; print(e.__file__, world.__file__)",
        ],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    assert [Path(f) for f in found] == [site / "evaluation/revisit.py", site / "world/__init__.py"]

    server = ServerProcess(tmp_path / "data").start()
    try:
        page = httpx.get(f"{server.url}/xr", timeout=10)
        assert page.status_code == 200 and "Start AR" in page.text
        assert "default-src 'self'" in page.headers["content-security-policy"]
        # Every module reachable from the page's entry point, as the browser would fetch them.
        todo, seen = ["/static/xr/main.mjs"], set()
        while todo:
            path = todo.pop()
            if path in seen:
                continue
            seen.add(path)
            answer = httpx.get(f"{server.url}{path}", timeout=10)
            assert answer.status_code == 200, path
            assert answer.headers["content-type"].startswith("text/javascript"), path
            base = path.rsplit("/", 1)[0]
            for relative in imports_of(answer.text):
                parts = base.split("/")
                for piece in relative.split("/"):
                    if piece == "..":
                        parts.pop()
                    elif piece != ".":
                        parts.append(piece)
                todo.append("/".join(parts))
        assert "/static/vendor/msgpack-msgpack@3.1.3/dist.esm/Decoder.mjs" in seen
        assert "/static/xr/encode-worker.mjs" in seen
    finally:
        server.stop()
