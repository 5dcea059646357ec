"""apps.progress_log: in a log (stderr not a terminal), progress bars become lines, at most one per few seconds,
with the bar's last state; text lines pass through at once."""

import io
import os
import subprocess
import sys

from apps.progress_log import LineProgress, progress_every

from helpers.paths import REPO


class _Clock:
    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_redraws_become_lines_one_per_interval_and_the_last_state_stays():
    out, clock = io.StringIO(), _Clock()
    s = LineProgress(out, every=5.0, clock=clock)
    s.write("INFO starting\n")
    for k in range(100):  # 100 redraws over 10 s: lines at 0 s and 5 s (and the final state)
        clock.now = k * 0.1
        s.write(f"\rprobe 1 of 5: {k:3d}%")
    s.write("\r" + " " * 20 + "\r")  # leave=False: the bar clears its line
    s.write("done\n")
    assert out.getvalue().splitlines() == [
        "INFO starting",
        "probe 1 of 5:   0%",
        "probe 1 of 5:  50%",
        "probe 1 of 5:  99%",
        "done",
    ]
    assert "\r" not in out.getvalue()


def test_a_bar_that_ends_its_line_is_written_once():
    out, clock = io.StringIO(), _Clock()
    s = LineProgress(out, every=5.0, clock=clock)
    s.write("\rtrain: 1/3")
    clock.now = 1.0
    s.write("\rtrain: 3/3")
    s.write("\rtrain: 3/3\n")  # leave=True: the final state, then a newline
    s.close_bars()
    assert out.getvalue().splitlines() == ["train: 1/3", "train: 3/3"]


def test_the_interval_comes_from_the_environment(monkeypatch):
    monkeypatch.setenv("FLUIDGS_PROGRESS_SECONDS", "2")
    assert progress_every() == 2.0
    monkeypatch.setenv("FLUIDGS_PROGRESS_SECONDS", "soon")
    assert progress_every() == 5.0


def test_the_cli_log_of_a_tqdm_bar_is_line_based():
    # a real tqdm bar through fluidgs' main, stderr a pipe: a handful of lines, no carriage return
    code = (
        "import time, tqdm, apps.progress_log as p\n"
        "with p.line_progress():\n"
        "    for _ in tqdm.tqdm(range(40), desc='work', mininterval=0):\n"
        "        time.sleep(0.01)\n"
    )
    env = {**os.environ, "FLUIDGS_PROGRESS_SECONDS": "0.15"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env, check=True)
    lines = proc.stderr.splitlines()
    assert "\r" not in proc.stderr and 2 <= len(lines) <= 8, proc.stderr
    assert lines[-1].startswith("work: 100%")
