"""The live monitor in whole swarms (``swarm --monitor``), its page in a real browser.

* headless Chromium (Debian's package) opens the page during a lockstep ground-truth run; a
  screenshot shows robots where the recording says they are (pixels of a few robots, through
  the page's exposed world -> pixel mapping), and the WebSocket's messages decode to the
  recorded states;
* a monitor killed mid-run leaves the recording equal to that of a run without a monitor, and
  the launcher reports its death and nothing else changes (exit status 0).

Waiting is always for a condition with a generous deadline: no timing is asserted.
"""

import asyncio
import os
import re
import signal
import subprocess
import sys
import threading
import time

import aiohttp
import numpy as np
import pytest
import rclpy  # noqa: F401  (a broken install must fail, not skip)
from browser import CHROMIUM, Chromium

from knode_swarm_ros.core import load_trajectories
from knode_swarm_ros.logic.monitor import decode_tick, pixel_of

pytestmark = pytest.mark.ros

WAIT_S = 240
# the page's robot colours by health (page.html COLOURS): ok, warn, error, stale, lost; on a loaded
# machine a robot may be drawn stale for a moment, which is its health, not its place
ROBOT_RGB = np.array([[26, 102, 230], [242, 191, 26], [217, 26, 26], [242, 140, 26], [128, 128, 128]])
_URL = re.compile(r'page at (http://127\.0\.0\.1:\d+/)')
_STEP = re.compile(r'\bstep (\d+)(?:/\d+)? \(t = ')  # the launcher's progress line


class Launcher:
    """``swarm`` in the background, its output lines collected as they come."""

    def __init__(self, tmp_path, *args):
        self.lines = []
        env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        cmd = [sys.executable, '-m', 'knode_swarm_ros.nodes.swarm', '--log-dir', str(tmp_path / 'logs')]
        cmd += ['--no-figure', '--domain-id', os.environ['ROS_DOMAIN_ID'], '--ground-truth', *map(str, args)]
        self.proc = subprocess.Popen(
            cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def wait_for(self, pattern: str) -> re.Match:
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            for line in list(self.lines):
                found = re.search(pattern, line)
                if found:
                    return found
            assert self.proc.poll() is None, '\n'.join(self.lines)
            time.sleep(0.1)
        raise AssertionError(f'{pattern!r} not seen:\n' + '\n'.join(self.lines))

    def wait_for_step(self, step: int) -> None:
        """Until the launcher's progress line reports a step >= ``step``."""
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            if any(int(m.group(1)) >= step for m in map(_STEP.search, list(self.lines)) if m):
                return
            assert self.proc.poll() is None, '\n'.join(self.lines)
            time.sleep(0.1)
        raise AssertionError(f'step {step} not reached:\n' + '\n'.join(self.lines))

    def finish(self, sig=None) -> int:
        if sig is not None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=WAIT_S)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()

    @property
    def output(self) -> str:
        return '\n'.join(self.lines)


async def _ticks(url: str, count: int, heard: int, most: int = 600):
    """The hello message and at least ``count`` tick messages of the page's WebSocket, more until
    they hold ``heard`` robots heard (a loaded machine starts the robots after the monitor's
    first ticks), at most ``most``."""
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(url.replace('http', 'ws') + 'ws') as ws:
            hello = (await ws.receive(timeout=WAIT_S)).data
            ticks, total = [], 0
            while len(ticks) < count or (total < heard and len(ticks) < most):
                ticks.append((await ws.receive(timeout=WAIT_S)).data)
                total += sum(h != 'unheard' for h in decode_tick(ticks[-1], 2)['health'])
            return hello, ticks


@pytest.fixture
def run_dir(tmp_path, ros_domain_id):
    return tmp_path


def test_page_in_chromium_shows_the_recorded_swarm(run_dir):
    assert os.path.exists(CHROMIUM), f'{CHROMIUM} is missing: apt-get install chromium (.ci/run does)'
    record = run_dir / 'run.npz'
    swarm = Launcher(run_dir, '--robots', 10, '--steps', 0, '--record', record, '--monitor', 0)
    browser = None
    try:
        url = swarm.wait_for(_URL.pattern).group(1)
        hello_text, ticks = asyncio.run(_ticks(url, 5, heard=10))
        browser = Chromium(url)
        browser.wait_until('window.monitor && monitor.received >= 3')
        shown = browser.evaluate('monitor.pause()')
        view = browser.evaluate('monitor.hello')
        pixels = browser.screenshot()
        # The recorder files a step a moment after the monitor shows it: stop once the run is
        # well past every step the page and the WebSocket showed, so the recording holds them.
        seen = max([shown['step']] + [decode_tick(t, 2)['step'] for t in ticks])
        swarm.wait_for_step(seen + 10)
    finally:
        if browser is not None:
            browser.close()
        code = swarm.finish(signal.SIGINT)  # the recorder saves what it has
    assert code in (0, 130), swarm.output
    states = load_trajectories(record, 'flock2d').states[0]  # [T, n, 4], one frame per step

    # The WebSocket's messages decode to the recorded states (mm rounding); a robot not heard yet
    # (a first tick can come before the first states are taken) is 'unheard', at the origin.
    compared = 0
    for text in ticks:
        tick = decode_tick(text, 2)
        heard = np.array([h != 'unheard' for h in tick['health']])
        assert not tick['positions'][~heard].any() and not tick['directions'][~heard].any()
        steps = (tick['step'] - tick['lags'])[heard]
        recorded = states[steps, np.arange(10)[heard]]
        np.testing.assert_allclose(tick['positions'][heard], recorded[:, :2], atol=6e-4)
        np.testing.assert_allclose(tick['directions'][heard], recorded[:, 2:], atol=6e-4)
        compared += int(heard.sum())
    assert compared >= 10  # at least a whole swarm's worth of robots checked

    # The screenshot shows robots where the recording says they are.
    assert view['scale'] > 0 and (view['width'], view['height']) == (960, 720)
    assert pixels.shape[:2] == (800, 1400)
    steps = shown['step'] - np.asarray(shown['lags'])
    for robot in (0, 4, 9):
        x, y = states[steps[robot], robot, :2]
        col, row = pixel_of(x, y, shown['c'], view['scale'], view['width'], view['height'])
        assert 0 <= col < 960 and 0 <= row < 720, (robot, col, row)
        rgb = pixels[int(row), int(col)].astype(int)  # the pixel that holds the point

        assert np.abs(rgb - ROBOT_RGB).max(axis=1).min() <= 40, (robot, rgb.tolist())
    # ... and nothing where no robot is: far corners of the canvas are background.
    assert (pixels[715, 955] >= 250).all() and (pixels[715, 5] >= 250).all()


def test_monitor_killed_mid_run_changes_nothing(run_dir):
    args = ('--robots', 8, '--steps', 2500, '--seed', 4)
    plain = Launcher(run_dir / 'plain', *args, '--record', run_dir / 'plain.npz')
    assert plain.finish() == 0, plain.output

    watched = Launcher(run_dir / 'watched', *args, '--record', run_dir / 'watched.npz', '--monitor', 0)
    pid = int(watched.wait_for(r'monitor \(pid (\d+)\)').group(1))
    watched.wait_for(_URL.pattern)
    os.kill(pid, signal.SIGKILL)
    assert watched.finish() == 0, watched.output
    assert 'the monitor (pid' in watched.output and 'killed by SIGKILL' in watched.output, watched.output
    assert 'the run goes on without it' in watched.output
    killed_at = next(i for i, line in enumerate(watched.lines) if 'killed by SIGKILL' in line)
    finished_at = next(i for i, line in enumerate(watched.lines) if 'the simulator has finished' in line)
    assert killed_at < finished_at, watched.output  # it died mid-run

    a = load_trajectories(run_dir / 'plain.npz', 'flock2d').states
    b = load_trajectories(run_dir / 'watched.npz', 'flock2d').states
    assert a.shape == b.shape and np.array_equal(a, b)
