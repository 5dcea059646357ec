"""A pool worker of `experiment` and `study oracle` stopped by SIGTERM leaves nothing to the resource tracker: its
progress bars' lock was a multiprocessing semaphore, unlinked only at a normal exit, so the tracker printed "There
appear to be 1 leaked semaphore objects" after every stopped study."""

import os
import signal
import subprocess
import sys
import textwrap
import time

from helpers.paths import REPO

# The job a worker runs: a progress bar (tqdm makes its lock here), then a wait for the parent's SIGTERM.
JOB = """
from pathlib import Path
from tqdm import tqdm

bar = tqdm(total=1, disable=True)
Path({started!r}).write_text("started")
import time
time.sleep(120)
"""

# The parent: the experiment's executor and signal handling, as `fluidgs experiment` uses them.
PARENT = """
import runpy, sys
from apps.options.executor import make_executor
from apps.signals import Stopped, stop_signals

if __name__ == "__main__":  # the spawned worker imports this file too
    try:
        with stop_signals():
            for _ in make_executor("local", 1, 1, None).map(runpy.run_path, [{job!r}]):
                pass
    except Stopped as exc:
        sys.exit(exc.exit_code)
"""


def test_a_worker_stopped_by_sigterm_leaks_no_semaphore(tmp_path):
    started = tmp_path / "started"
    (tmp_path / "job.py").write_text(textwrap.dedent(JOB.format(started=str(started))))
    (tmp_path / "parent.py").write_text(textwrap.dedent(PARENT.format(job=str(tmp_path / "job.py"))))
    proc = subprocess.Popen(
        [sys.executable, str(tmp_path / "parent.py")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        start_new_session=True,
    )
    t0 = time.monotonic()
    while not started.exists():
        assert proc.poll() is None and time.monotonic() - t0 < 120, proc.stderr.read()[-3000:]
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err[-3000:]
    assert "leaked" not in err and "Traceback" not in err, err[-3000:]
