"""`semanticxr demo`: after the network comes back the device continues its walk where it was
(the server counts each frame of the walk once), its output in a log is one line per update
(no carriage returns), and its living-map step walks the same path again after a scripted
move and asks where the moved thing is."""

from __future__ import annotations

import argparse
import asyncio
import re
import subprocess
import sys

import pytest
from analytic_world import KITCHEN, RectSource
from helpers_device import FAST_KNOBS

from client_sim.netem import NetemProxy
from client_sim.streaming import DeviceClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]


class Recording(RectSource):
    """A RectSource that remembers which frames the device read."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.read: list[int] = []

    def frame(self, index: int):
        self.read.append(index)
        return super().frame(index)


def test_a_stream_started_where_the_last_one_stopped_continues_the_walk(live_server):
    server = live_server()
    port = int(server.url.rsplit(":", 1)[1])
    walk = Recording(KITCHEN, 10)

    async def scenario(proxy: NetemProxy) -> dict:
        sid, token, _ = await DeviceClient.create_session(server.url, knobs=FAST_KNOBS)
        device = DeviceClient(proxy.url(), sid, token)
        await device.stream(walk, fps=None, limit=6)
        await asyncio.to_thread(proxy.cut)
        await asyncio.to_thread(proxy.restore)
        await device.stream(walk, fps=None, start=6)
        await device.stop()
        session = await DeviceClient.fetch_session(server.url, sid, token)
        return {"session": session, "sent": device.stats.frames_sent}

    with NetemProxy("127.0.0.1", port) as proxy:
        r = asyncio.run(scenario(proxy))
    assert walk.read == list(range(10))
    assert r["sent"] == r["session"].frames == 10


def test_a_stream_refuses_a_negative_start():
    device = DeviceClient("http://127.0.0.1:9", "s", "t")
    with pytest.raises(ValueError, match="start"):
        asyncio.run(device.stream(RectSource(KITCHEN, 3), fps=None, start=-1))


def test_the_demo_continues_its_walk_after_the_outage_and_logs_one_line_per_update():
    pytest.importorskip("client_sim.sources.synthetic")
    frames = 70  # a short apartment walk on which the script moves something (a coffee maker)
    result = subprocess.run(
        [sys.executable, "-m", "app.cli", "demo", "--frames", str(frames), "--port", "0"]
        + ["--no-viewer", "--exit"],
        capture_output=True,
        text=True,
        timeout=200,
    )
    out = result.stdout
    assert result.returncode == 0, (out, result.stderr)
    assert "\r" not in out + result.stderr  # a pipe: plain lines, no live line or bar
    assert re.search(r"^ready: dashboard http://127\.0\.0\.1:\d+/", out, re.M)
    progress = re.findall(rf"^  frames (\d+)/{frames}\b", out, re.M)
    assert progress and all(int(n) <= frames for n in progress)
    assert "the device resumes its updates from its last one and continues its walk" in out
    walked = re.search(
        rf"^walk continued: yes — the server counted {frames} frames \((\d+) whole, (\d+) "
        rf"sightings\) of the {frames}-frame walk$",
        out,
        re.M,
    )
    assert walked and int(walked[1]) + int(walked[2]) == frames, out
    assert "caught up: yes" in out

    # the living-map step: the same path again, the moved thing asked after twice
    moved = re.search(r"^while you were out, someone moved the (.+?) \(from .+ to .+\)", out, re.M)
    assert moved, out
    question = f"'where is the {moved[1]}?'"
    assert len(re.findall(rf"^  \[SQ\] {re.escape(question)}: ", out, re.M)) == 2
    assert f"walking the same path again: frames {frames}..{2 * frames - 1}" in out
    assert re.search(rf"^  frames {2 * frames}/{2 * frames} sent$", out, re.M)
    assert out.count("caught up: yes") == 2  # after the outage, after the second walk
    assert re.search(
        r"^the script made \d+ changes; the map concluded \d+ on the second", out, re.M
    )
    assert re.search(rf"^the {re.escape(moved[1])}'s answer followed it: (yes|NO) — ", out, re.M)
    assert re.search(r"^  the device's local map answers the same: (yes|NO) — \[LQ\]", out, re.M)
    assert "[SQ include=removed] 'where did I last see the " in out
    assert re.search(r"last seen (just now|\d+ (s|min) ago)", out)


def test_a_walk_too_short_for_the_script_to_move_anything_skips_the_step_and_says_so(capsys):
    from app.cli.demo import _walk_source

    source, shown = _walk_source(argparse.Namespace(scene="apartment", frames=10, no_revisit=False))
    assert len(source) == 20 and shown is None
    assert "the living-map step is skipped" in capsys.readouterr().out


def test_without_the_revisit_the_walk_is_the_revisits_first_walk_unscripted(capsys):
    from app.cli.demo import _walk_source
    from world.changes import REVISIT_FPS

    source, shown = _walk_source(argparse.Namespace(scene="apartment", frames=10, no_revisit=True))
    assert len(source) == 10 and shown is None and source.fps == REVISIT_FPS
    assert capsys.readouterr().out == ""


class Terminal:
    """A stdout that says it is a terminal, keeping what was written."""

    def __init__(self, tty: bool):
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, text: str) -> int:
        self.text += text
        return len(text)

    def flush(self) -> None:
        pass


@pytest.mark.parametrize("tty", [True, False])
def test_progress_is_a_live_line_on_a_terminal_and_one_line_per_update_in_a_log(monkeypatch, tty):
    from app.cli.demo import _Console

    out = Terminal(tty)
    monkeypatch.setattr(sys, "stdout", out)
    console = _Console()
    console.progress("frames 1/3")
    console.progress("frames 2/3")
    console.say("device: reconnected")
    console.progress("frames 3/3")
    console.say("done")
    if tty:  # redrawn in place; cleared before any other line
        assert out.text == (
            "\r\x1b[Kframes 1/3\r\x1b[Kframes 2/3\r\x1b[Kdevice: reconnected\n"
            "\r\x1b[Kframes 3/3\r\x1b[Kdone\n"
        )
    else:
        assert out.text.splitlines() == [
            "frames 1/3",
            "frames 2/3",
            "device: reconnected",
            "frames 3/3",
            "done",
        ]
