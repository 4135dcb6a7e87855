"""Sweeps: cells (points of a product of axes, or any list of tasks) run in this process or as
tasks on Ray, resumable, a failed or killed cell retried once, progress in ``OUT/sweep.log``.

Used by ``python -m training.sweep`` (one ordinary training run per cell, :func:`train_cell`) and
``python -m training.grid`` (training and a test-set evaluation per cell).

A cell's record in ``OUT/sweep.json`` (:func:`run_cells`)::

    {"name": "policy.k=6,seed=0", "values": {"policy.k": 6, "seed": 0}, "run_dir": "OUT/policy.k=6,seed=0",
     "status": "done", "attempts": 1, "seconds": 12.3, "metrics": {...}, "error": null}

``status``: ``pending`` / ``running`` while the sweep runs; at its end ``done``, ``failed`` (two
attempts failed: an exception or a dead worker; ``error`` says why) or ``skipped`` (not run: the
sweep was interrupted first, or another process holds the cell). Ray is needed only for several
workers or a cluster (``--address``); it is the ``sweep`` extra of setup.py.
"""

from __future__ import annotations

import collections
import itertools
import json
import os
import re
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.yaml_file import load_yaml

from .records import write_json

RAY_PIN = 'ray==2.60.0'
ATTEMPTS = 2  # a cell is tried at most twice: one retry for a dead worker or a passing fault
PROGRESS_EVERY_S = 30.0  # a progress line at least this often while cells run
#: Folders of a checkout not shipped to a cluster (data and outputs must lie on a shared filesystem).
CLUSTER_EXCLUDES = ['.git', '.venv', 'data', 'runs', 'sweeps', 'out']


@dataclass
class Cell:
    """One task of a sweep: ``fn()`` (picklable: a module-level function or a ``functools.partial``
    of one) runs it and returns its result dict, or None when another process holds it.
    ``previous``: the result of an earlier run, found by the caller; the cell is then not run."""

    name: str
    values: Dict[str, Any]
    run_dir: str
    fn: Callable[[], Optional[Dict[str, Any]]]
    previous: Optional[Dict[str, Any]] = None
    record: Dict[str, Any] = field(default_factory=dict)


# -- axes -----------------------------------------------------------------------------------------


def parse_axis(text: str) -> Tuple[str, List[Any]]:
    """``'policy.k=6,10'`` -> ``('policy.k', [6, 10])``; each value parsed as YAML (as ``--set``)."""
    import yaml

    key, sep, values = text.partition('=')
    key = key.strip()
    if not sep or not key or not values.strip():
        raise ConfigError(f'--axis {text!r}: expected KEY=VALUE,VALUE,... (e.g. policy.k=6,10 or seed=0,1,2)')
    try:
        parsed = [load_yaml(v) for v in values.split(',')]
    except yaml.YAMLError as exc:
        raise ConfigError(f'--axis {text!r}: a value is not valid YAML ({exc})') from None
    if len(set(map(repr, parsed))) != len(parsed):
        raise ConfigError(f'--axis {text!r}: a value appears twice')
    return key, parsed


def axis_product(axes: Sequence[Tuple[str, List[Any]]]) -> List[Dict[str, Any]]:
    """Every point of the axes' product, the last axis fastest: ``[{'policy.k': 6, 'seed': 0}, ...]``."""
    keys = [k for k, _ in axes]
    if len(set(keys)) != len(keys):
        raise ConfigError(f'--axis: a key is given twice ({", ".join(keys)})')
    return [dict(zip(keys, combo)) for combo in itertools.product(*(v for _, v in axes))]


def cell_name(values: Dict[str, Any]) -> str:
    """A cell's directory name: ``policy.k=6,seed=0`` (characters a path dislikes become ``-``)."""

    def text(v):
        return format(v, 'g') if isinstance(v, float) else str(v)

    return ','.join(f'{k}={re.sub(r"[^A-Za-z0-9._+-]", "-", text(v))}' for k, v in values.items()) or 'base'


# -- one training run per cell ---------------------------------------------------------------------


def check_files(option: str, paths: Sequence[str]) -> None:
    """Refuse a missing input file before any cell runs (each would fail twice, quietly)."""
    for path in paths:
        if not os.path.isfile(path):
            raise ConfigError(f'{option} {path}: no such file')


def _plain(obj: Any) -> Any:
    """``obj`` as JSON reads it back (tuples become lists), so configs compare with stored ones."""
    return json.loads(json.dumps(obj))


def finished_cell(run_dir: str, cfg: Dict[str, Any], data: Any) -> Optional[Dict[str, Any]]:
    """The result of a finished :func:`train_cell` in ``run_dir`` for this config and data, or None.

    Raises:
        ConfigError: ``run_dir`` holds a finished run of another config or data.
    """
    path = os.path.join(run_dir, 'cell.json')
    if not os.path.exists(path):
        return None
    with open(path) as fh:
        previous = json.load(fh)
    if previous.get('config') != _plain(cfg) or previous.get('data') != _plain(data):
        raise ConfigError(
            f'{run_dir} holds a finished run of another config or data; '
            'use a new --out (or remove that directory)'
        )
    return previous


def train_cell(cfg: Dict[str, Any], data: Any, run_dir: str) -> Dict[str, Any]:
    """One ordinary training run (:class:`~training.learning.trainer.Trainer`) in ``run_dir``, resumed
    from its checkpoint when a former attempt left one; writes ``run_dir/cell.json`` last.

    Returns ``{'config', 'data', 'epochs', 'selected', 'train_seconds', 'metrics'}``, ``metrics``
    the selection record of the chosen epoch (``score``, ``avd_final``, ...; empty without selection).
    """
    from .trainer import Trainer

    os.makedirs(run_dir, exist_ok=True)
    log_path = os.path.join(run_dir, 'train.log')

    def log(*parts):
        with open(log_path, 'a') as fh:
            fh.write(' '.join(map(str, parts)) + '\n')

    resume = os.path.exists(os.path.join(run_dir, 'checkpoint.pt'))
    summary = Trainer(cfg, data, run_dir, resume=resume, progress=False, log=log).run()
    best = summary.get('best') or {}
    result = {
        'config': _plain(cfg),
        'data': _plain(data),
        'epochs': summary['epochs'],
        'selected': summary['selected'],
        'train_seconds': summary['train_seconds'],
        'metrics': best.get('metrics') or {},
    }
    write_json(os.path.join(run_dir, 'cell.json'), result)
    return result


def call_cell(fn: Callable[[], Optional[Dict[str, Any]]]) -> Optional[Dict[str, Any]]:
    """Run one cell in a worker with one torch thread: the workers share the machine's cores."""
    import torch

    torch.set_num_threads(1)
    return fn()


# -- where cells run -------------------------------------------------------------------------------


class InProcess:
    """Cells one after another in this process (no Ray needed)."""

    def __init__(self) -> None:
        self.waiting: collections.OrderedDict = collections.OrderedDict()
        self.slots = 1

    def submit(self, fn) -> object:
        handle = object()
        self.waiting[handle] = fn
        return handle

    def wait(self, timeout: float) -> List[Tuple[object, bool, Any]]:
        """Run the oldest submitted cell: ``[(handle, ok, result or error text)]``."""
        handle, fn = self.waiting.popitem(last=False)
        try:
            return [(handle, True, call_cell(fn))]
        except Exception as exc:  # a failed cell is reported in its record; the others go on
            return [(handle, False, f'{type(exc).__name__}: {exc}')]

    def cancel(self) -> None:
        self.waiting.clear()

    def close(self) -> None:
        pass


class OnRay:
    """Cells as Ray tasks: a local Ray of ``workers`` CPUs, or the cluster at ``address``. A Ray
    already initialised by the caller is used as it is (and left running)."""

    def __init__(self, workers: int, address: Optional[str] = None):
        ray = import_ray(workers, address)
        self.ray = ray
        self.started = not ray.is_initialized()
        if self.started:
            common = {'include_dashboard': False, 'log_to_driver': False}
            if address:
                from .records import repo_root

                root = repo_root() or os.getcwd()
                ray.init(
                    address=address,
                    runtime_env={'working_dir': root, 'excludes': CLUSTER_EXCLUDES},
                    **common,
                )
            else:
                # a small object store: results are a few kB, and /dev/shm is shared with others
                ray.init(num_cpus=workers, object_store_memory=128 * 2**20, **common)
        self.slots = workers
        # retries are ours (one per cell, for an exception or a dead worker alike), not Ray's
        self.remote = ray.remote(num_cpus=1, max_retries=0, retry_exceptions=False)(call_cell)
        self.refs: Dict[Any, Any] = {}

    def submit(self, fn) -> object:
        ref = self.remote.remote(fn)
        self.refs[ref] = ref
        return ref

    def wait(self, timeout: float) -> List[Tuple[object, bool, Any]]:
        ready, _ = self.ray.wait(list(self.refs), num_returns=1, timeout=timeout)
        out = []
        for ref in ready:
            del self.refs[ref]
            try:
                out.append((ref, True, self.ray.get(ref)))
            except self.ray.exceptions.RayTaskError as exc:  # the cell raised
                cause = getattr(exc, 'cause', None) or exc
                out.append((ref, False, f'{type(cause).__name__}: {str(cause).strip().splitlines()[-1]}'))
            except self.ray.exceptions.RayError as exc:  # its worker died (killed, out of memory)
                out.append((ref, False, f'{type(exc).__name__}: {str(exc).strip().splitlines()[0]}'))
        return out

    def cancel(self) -> None:
        for ref in self.refs:
            self.ray.cancel(ref, force=True)
        self.refs.clear()

    def close(self) -> None:
        if self.started:
            self.ray.shutdown()


def import_ray(workers: int, address: Optional[str]):
    """The ``ray`` module, or a :class:`ConfigError` saying how to install it."""
    try:
        import ray
    except ImportError:
        what = f'--address {address}' if address else f'--workers {workers}'
        raise ConfigError(
            f'{what} runs cells on Ray, which is not installed: pip install {RAY_PIN} '
            "(or pip install '.[sweep]'), or run with --workers 1 (in this process)"
        ) from None
    return ray


def backend(workers: int, address: Optional[str] = None):
    """In this process for one local worker, else Ray."""
    if workers < 1:
        raise ConfigError(f'--workers must be >= 1, got {workers}')
    return InProcess() if workers == 1 and not address else OnRay(workers, address)


# -- the scheduler ---------------------------------------------------------------------------------


class Progress:
    """Progress lines on stdout and in ``OUT/sweep.log`` (time-stamped, flushed per line)."""

    def __init__(self, out: str, total: int, slots: int, echo=print):
        self.path = os.path.join(out, 'sweep.log')
        self.total, self.slots, self.echo = total, slots, echo
        self.t0 = time.monotonic()
        self.durations: List[float] = []
        self.last = 0.0

    def line(self, text: str) -> None:
        self.last = time.monotonic()
        self.echo(text, flush=True)
        with open(self.path, 'a') as fh:
            fh.write(time.strftime('%Y-%m-%d %H:%M:%S ') + text + '\n')

    def status(self, cells: List[Cell], note: str = '') -> None:
        count = collections.Counter(c.record['status'] for c in cells)
        left = count['pending'] + count['running']
        if not left:
            eta = 'none left'
        elif self.durations:
            mean = sum(self.durations) / len(self.durations)
            eta = f'about {_clock(mean * left / max(1, min(self.slots, left)))} left'
        else:
            eta = 'time left unknown until a cell finishes'
        self.line(
            f'sweep: {count["done"]}/{self.total} done, {count["running"]} running, {count["failed"]} failed, '
            f'{count["pending"]} pending; {_clock(time.monotonic() - self.t0)} elapsed, {eta}'
            + (f' ({note})' if note else '')
        )


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return (
        f'{seconds // 3600}h{seconds // 60 % 60:02d}m'
        if seconds >= 3600
        else f'{seconds // 60}m{seconds % 60:02d}s'
    )


def run_cells(
    cells: List[Cell],
    out: str,
    workers: int = 1,
    address: Optional[str] = None,
    header: Optional[Dict[str, Any]] = None,
    echo=print,
) -> List[Dict[str, Any]]:
    """Run every cell not finished before (``Cell.previous``), at most ``workers`` at a time, each
    tried at most :data:`ATTEMPTS` times; ``OUT/sweep.json`` (``header`` plus ``cells``: the records)
    is rewritten atomically at every change. Returns the records, in the cells' order.

    A Ctrl-C stops the running cells and marks the unfinished ones ``skipped`` before it propagates.
    """
    os.makedirs(out, exist_ok=True)
    for cell in cells:
        cell.record = {
            'name': cell.name,
            'values': cell.values,
            'run_dir': cell.run_dir,
            'status': 'pending',
            'attempts': 0,
            'seconds': None,
            'metrics': None,
            'error': None,
        }
        if cell.previous is not None:
            _finish(cell, cell.previous, None)
    header = dict(header or {})

    def save():
        write_json(os.path.join(out, 'sweep.json'), {**header, 'cells': [c.record for c in cells]})

    todo = collections.deque(c for c in cells if c.record['status'] == 'pending')
    runner = backend(workers, address) if todo else None
    progress = Progress(out, len(cells), 1 if runner is None else runner.slots, echo)
    running: Dict[object, Tuple[Cell, float]] = {}
    save()
    progress.status(cells, f'{len(cells) - len(todo)} finished before' if len(todo) < len(cells) else 'start')
    try:
        while todo or running:
            while todo and len(running) < runner.slots:
                cell = todo.popleft()
                cell.record.update(status='running', attempts=cell.record['attempts'] + 1)
                running[runner.submit(cell.fn)] = (cell, time.monotonic())
            save()
            outcomes = runner.wait(timeout=PROGRESS_EVERY_S)
            for handle, ok, value in outcomes:
                cell, t0 = running.pop(handle)
                seconds = time.monotonic() - t0
                if ok:
                    _finish(cell, value, seconds)
                    progress.durations.append(seconds)
                    note = f'{cell.name} {cell.record["status"]} in {seconds:.1f} s'
                elif cell.record['attempts'] < ATTEMPTS:
                    cell.record.update(status='pending', error=value)
                    todo.appendleft(cell)
                    note = f'{cell.name} failed ({value}); retrying'
                else:
                    cell.record.update(status='failed', error=value, seconds=round(seconds, 1))
                    note = f'{cell.name} failed twice ({value})'
                save()
                progress.status(cells, note)
            if not outcomes and time.monotonic() - progress.last >= PROGRESS_EVERY_S:
                progress.status(cells)
    except BaseException:
        runner.cancel()
        for cell in cells:
            if cell.record['status'] in ('pending', 'running'):
                cell.record['status'] = 'skipped'
        save()
        raise
    finally:
        if runner is not None:
            runner.close()
    return [c.record for c in cells]


def _finish(cell: Cell, result: Optional[Dict[str, Any]], seconds: Optional[float]) -> None:
    """A cell's record from its result: ``done``, or ``skipped`` when another process holds it."""
    if result is None:
        cell.record.update(status='skipped', error='claimed by another process')
        return
    cell.record.update(
        status='done',
        metrics=result.get('metrics'),
        error=result.get('error'),
        seconds=None if seconds is None else round(seconds, 1),
    )
