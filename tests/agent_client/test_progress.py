"""Progress bars: tqdm on a terminal, whole lines in a log, correct final line."""

from __future__ import annotations

import io
import subprocess
import sys

from agent_client.progress import progress_bar
from agent_client.rl.scalars import Progress


def test_a_log_gets_whole_lines_and_the_final_count():
    out = io.StringIO()  # not a terminal
    with progress_bar(1000, "train", unit="step", file=out) as bar:
        for _ in range(1000):
            bar.update(1)
    text = out.getvalue()
    assert "\r" not in text and text.endswith("\n")
    lines = text.splitlines()
    assert lines[0].startswith("train:") and "0/1000" in lines[0]
    assert "1000/1000" in lines[-1]  # the final line says where it ended
    assert len(lines) <= 3  # a line every 30 s, and at the start and the end: not one per update


def test_disabled_bar_writes_nothing():
    out = io.StringIO()
    with progress_bar(10, "x", enabled=False, file=out) as bar:
        bar.update(10)
    assert out.getvalue() == ""


def test_training_progress_final_line_has_a_rate_and_no_inf():
    """The old bar ended with '0 steps/s ... eta inf min'; the final line now has a real rate."""
    code = (
        "import sys, time\n"
        "from agent_client.rl.scalars import Progress\n"
        "p = Progress(200, initial=100)\n"
        "for s in range(101, 201):\n"
        "    time.sleep(0.001)\n"
        "    p.update(s, 0.05, 1.5)\n"
        "p.update(200, 0.05, 1.5, force=True)\n"
        "p.close()\n"
    )
    err = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stderr
    last = err.strip().splitlines()[-1]
    assert "200/200" in last and "eps 0.050" in last and "inf" not in last
    assert "step/s" in last or "s/step" in last
    assert Progress(10, enabled=False).tty in (True, False)
