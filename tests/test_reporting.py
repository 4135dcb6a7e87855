"""The nodes' shared log throttle and JSON report (logic/reporting.py), without ROS."""

import json
import os

from knode_swarm_ros.logic.reporting import Throttle, throttled_log, write_json_report


def test_throttle_lets_each_key_log_once_per_period():
    t = Throttle(5.0, clock=lambda: 0.0)
    assert t.ready('a', 100.0) and not t.ready('a', 104.9) and t.ready('b', 104.9)
    assert t.ready('a', 105.0) and not t.ready('a', 109.0)
    assert t.ready('c')  # the clock's time: 0.0, first time for c
    assert not t.ready('c')


class _Logger:
    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    def warning(self, text):
        self.lines.append(('warn', text))


def test_throttled_log_uses_the_severity_and_the_throttle():
    now = [0.0]
    log, t = _Logger(), Throttle(5.0, clock=lambda: now[0])
    throttled_log(log, t, 'k', 'one', warn=True)
    throttled_log(log, t, 'k', 'two')
    now[0] = 6.0
    throttled_log(log, t, 'k', 'three')
    assert log.lines == [('warn', 'one'), ('info', 'three')]


def test_write_json_report_replaces_the_file_whole_and_skips_an_empty_path(tmp_path):
    path = tmp_path / 'sub' / 'report.json'
    write_json_report(str(path), {'a': 1})
    write_json_report(str(path), {'b': 2, 'p': path}, indent=1, default=str)
    assert json.loads(path.read_text()) == {'b': 2, 'p': str(path)}
    assert os.listdir(path.parent) == ['report.json']  # no temporary file left
    write_json_report('', {'c': 3})  # no report asked for: nothing written
    assert os.listdir(path.parent) == ['report.json']
