"""Mutation testing of the core and the ROS-free node logic with cosmic-ray.

    python tools/mutation.py [--only knowledge,network] [--sample N --seed S] [--workdir out/mutation]

cosmic-ray (a maintained tool) enumerates the mutants of every module of :data:`MODULES`
(``knode_swarm_ros/core/**`` and ``nodes/*_logic.py``) into its session database; this script
runs them, cheaply, and writes each result back into that database (``cosmic-ray dump`` works).

Cost per mutant, and how it is kept small:
- one coverage run first (``tools/mutation_cov.py``) maps every line to the fast tests
  (``-m "not ros"``) that execute it, with each test's duration;
- a mutant runs only the tests that execute its line(s), fastest first, stopping at the
  first failure (``-x``); a line no test executes in-process (import-time code such as
  constants and default arguments, code reached only through TorchScript or a child process)
  runs every test of its module instead (``fallback``; when no test runs any line of the module
  inside a test, as for constants or a package ``__init__`` run at collection, the tests whose
  file names the module), never skipped: an unexecuted mutant that survives is listed as a
  survivor like any other;
- a mutant that survives the tests it ran is run against the module's other tests, those that
  run a line of it and those whose file names it, before it counts as a survivor
  (``confirmed``): a memoised result is attributed to the first test that computed it only,
  and a test that only reads an import-time constant (a preset's field) runs no line of it;
- torch, numpy and pytest are imported once; each mutant runs ``pytest.main`` in a forked
  child (one torch thread), so no interpreter start per mutant;
- a mutant whose tests run 5x their measured time + 300 s (room for a loaded machine) is
  stopped and counted as a timeout (killed, as cosmic-ray counts it).

Everything happens in a copy of the repository under ``--workdir`` (the checkout is never
touched). Prints per module killed / timed out / survived / incompetent, the score
killed / (killed + survived) with a 95 % Wilson interval when ``--sample`` drew the mutants,
mutants per minute, and every survivor as ``file:line operator``; ``results.json`` keeps it.
Exit status: 0 when every module ran, 1 otherwise, 2 for bad arguments (a score below the goal
is reported, not an error: see docs/testing.md).

Why cosmic-ray and not mutmut: mutmut 3 replaces every function by a trampoline, which
TorchScript cannot compile, and the policy's maths is exported as TorchScript.

Operators left out (``EXCLUDED``): bitwise/shift replacements of arithmetic operators and
``is``/``is not`` swaps of value comparisons. On the float arrays and tensors of this code
they raise TypeError at once, so they tell nothing.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXCLUDED = [
    r'core/ReplaceBinaryOperator_\w+_(BitOr|BitAnd|BitXor|LShift|RShift)$',
    r'core/ReplaceComparisonOperator_(Eq|NotEq|Lt|LtE|Gt|GtE)_(Is|IsNot)$',
]
# The test pool the coverage run maps: every fast test file except those that only drive
# other processes (colcon build, a throw-away suite) and the ROS ones (-m "not ros").
POOL_EXCLUDE = ('test_ros_', 'test_launcher_basics', 'test_colcon_layout', 'test_no_silent_skips')


def _modules() -> dict:
    """name -> path of every mutated module: core (groundtruth included) and nodes/*_logic."""
    paths = sorted((ROOT / 'knode_swarm_ros' / 'core').rglob('*.py'))
    paths += sorted((ROOT / 'knode_swarm_ros' / 'nodes').glob('*_logic.py'))
    out = {}
    for p in paths:
        rel = p.relative_to(ROOT).as_posix()
        name = p.parent.name + '_init' if p.stem == '__init__' else p.stem
        out[name] = rel
    return out


MODULES = _modules()


def _copy_tree(dest: Path) -> None:
    """Tracked and untracked-but-not-ignored files of the checkout, copied to ``dest``."""
    files = subprocess.run(
        ['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout.split(b'\0')
    if dest.exists():
        shutil.rmtree(dest)
    for name in filter(None, files):
        src = ROOT / name.decode()
        if src.is_file():
            (dest / name.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name.decode())


def coverage_map(tree: Path, out: Path) -> dict:
    """Run the test pool once under ``tools/mutation_cov.py``; ``{'lines', 'durations'}``."""
    pool = sorted(
        f'tests/{p.name}' for p in (tree / 'tests').glob('test_*.py') if not p.name.startswith(POOL_EXCLUDE)
    )
    env = dict(os.environ, MUTATION_COV_OUT=str(out))
    subprocess.run(
        [
            sys.executable,
            '-m',
            'pytest',
            '-p',
            'tools.mutation_cov',
            '-q',
            '-p',
            'no:cacheprovider',
            '-m',
            'not ros',
            *pool,
        ],
        cwd=tree,
        env=env,
        stdout=subprocess.DEVNULL,
        check=False,
    )
    return json.loads(out.read_text())


def _config(module: str, timeout: float) -> str:
    # cosmic-ray needs a test command in its config; this script runs the tests itself.
    return '\n'.join(
        [
            '[cosmic-ray]',
            f'module-path = "{module}"',
            f'timeout = {timeout}',
            'excluded-modules = []',
            'test-command = "python -m pytest -x -m \\"not ros\\" tests"',
            '',
            '[cosmic-ray.distributor]',
            'name = "local"',
            '',
            '[cosmic-ray.filters.operators-filter]',
            f'exclude-operators = {json.dumps(EXCLUDED)}',
            '',
        ]
    )


def _tool(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _importers(tree: Path, module: str, tests) -> set:
    """The tests whose file names ``module``: ``a.b.c`` anywhere, or ``from a.b import (..., c, ...)``."""
    dotted = module[:-3].replace('/', '.').removesuffix('.__init__')
    parent, _, stem = dotted.rpartition('.')
    from_import = re.compile(rf'from\s+{re.escape(parent)}\s+import\s+(\([^)]*\)|[^\n]*)')

    def names(text: str) -> bool:
        return dotted in text or any(re.search(rf'\b{stem}\b', g) for g in from_import.findall(text))

    files = {t.split('::')[0] for t in tests}
    named = {f for f in files if names((tree / f).read_text())}
    return {t for t in tests if t.split('::')[0] in named}


def _confirm_pool(cov: dict, module: str, tree: Path) -> list:
    """Every test that runs a line of ``module`` or whose file names it, fastest first: a survivor
    is run against these too (a memoised result is credited to its first test only; a test that
    only reads an import-time constant, e.g. a preset's field, runs no line of the module)."""
    dur = cov['durations']
    tests = {t for ts in cov['lines'].get(module, {}).values() for t in ts if t}
    tests |= _importers(tree, module, dur)
    return sorted(tests, key=lambda t: (dur.get(t, 0.0), t))


def _select(cov: dict, module: str, first: int, last: int, tree: Path):
    """(test ids fastest first, mode) for a mutant on lines first..last: the tests that run those
    lines ('covered'); else every test that runs a line of the module ('fallback'); else (only
    import-time lines, e.g. constants, a package ``__init__``) the tests whose file names the
    module ('importers'); else all of them ('all')."""
    lines, dur = cov['lines'].get(module, {}), cov['durations']
    tests = {t for n in range(first, last + 1) for t in lines.get(str(n), []) if t}
    mode = 'covered'
    if not tests:
        tests, mode = {t for ts in lines.values() for t in ts if t}, 'fallback'
    if not tests:
        tests, mode = _importers(tree, module, dur), 'importers'
    if not tests:
        tests, mode = set(dur), 'all'
    return sorted(tests, key=lambda t: (dur.get(t, 0.0), t)), mode


def _run_tests(tree: Path, tests, timeout: float, log: Path):
    """Fork, run ``pytest -x tests`` in the child; (pytest exit status | 'timeout' | 'signal')."""
    pid = os.fork()
    if pid == 0:  # child: never returns
        try:
            os.setpgid(0, 0)
            fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            os.chdir(tree)
            sys.path.insert(0, str(tree))
            sys.dont_write_bytecode = True
            import pytest

            # --assert=plain: no rewriting of the test modules (1.4 s a run without .pyc
            # files; a failing assert fails the same); no:unraisableexception: its
            # gc.collect() over torch's heap costs 1.5 s a run.
            rc = pytest.main(
                [
                    '-x',
                    '-q',
                    '-p',
                    'no:cacheprovider',
                    '-p',
                    'no:unraisableexception',
                    '--assert=plain',
                    '-m',
                    'not ros',
                    f'--basetemp={tree.parent / "tmp"}',
                    *tests,
                ]
            )
        except BaseException:
            rc = 3
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(int(rc))
    deadline = time.monotonic() + timeout
    try:
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return os.waitstatus_to_exitcode(status) if os.WIFEXITED(status) else 'signal'
            if time.monotonic() > deadline:
                return 'timeout'
            time.sleep(0.05)
    finally:  # timeout, Ctrl-C or SIGTERM: the run and whatever it started end with us
        try:
            os.killpg(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
        except (ProcessLookupError, ChildProcessError):
            pass


def _sample(work_db, size: int, seed: int) -> None:
    """Keep a seeded random ``size`` of the pending mutants; mark the rest skipped."""
    import random

    from cosmic_ray.work_item import WorkerOutcome, WorkResult

    # cosmic-ray's job ids are random: order by what the mutant is, so a seed draws the same sample
    def key(it):
        return (
            str(it.mutations[0].module_path),
            tuple(it.mutations[0].start_pos),
            it.mutations[0].operator_name,
            it.mutations[0].occurrence,
        )

    pending = [it.job_id for it in sorted(work_db.pending_work_items, key=key)]
    keep = set(random.Random(seed).sample(pending, min(size, len(pending))))
    for job_id in pending:
        if job_id not in keep:
            work_db.set_result(
                job_id, WorkResult(output='not in the sample', worker_outcome=WorkerOutcome.SKIPPED)
            )


def run_module(tree: Path, name: str, module: str, cov: dict, sample: int = 0, seed: int = 0) -> dict:
    import cosmic_ray.plugins
    from cosmic_ray.mutating import use_mutation
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome, WorkResult

    cfg, db = tree.parent / f'{name}.toml', tree.parent / f'{name}.sqlite'
    cfg.write_text(_config(module, 60.0))
    db.unlink(missing_ok=True)
    run = lambda *a: subprocess.run(a, cwd=tree, check=True, stdout=subprocess.DEVNULL)  # noqa: E731
    run(_tool('cosmic-ray'), 'init', str(cfg), str(db))
    run(_tool('cr-filter-operators'), str(db), str(cfg))
    run(_tool('cr-filter-pragma'), str(db))
    counts = dict.fromkeys(('killed', 'timeout', 'survived', 'incompetent', 'fallback'), 0)
    survivors, total = [], 0
    with use_db(str(db), WorkDB.Mode.open) as work_db:
        total = len(list(work_db.pending_work_items))
        if sample:
            _sample(work_db, sample, seed)
        for item in list(work_db.pending_work_items):
            m = item.mutations[0]
            tests, mode = _select(cov, module, m.start_pos[0], m.end_pos[0], tree)
            counts['fallback'] += mode != 'covered'
            budget = 5 * sum(cov['durations'].get(t, 1.0) for t in tests) + 300  # a loaded machine is slow
            log = tree.parent / 'last_mutant.log'
            operator = cosmic_ray.plugins.get_operator(m.operator_name)()
            try:
                mutation = use_mutation(tree / m.module_path, operator, m.occurrence)
                mutated = mutation.__enter__()[1]
            except Exception as exc:
                mutation, mutated, rc = None, None, f'operator failed: {exc!r}'
            try:
                if mutation is None:
                    pass
                elif mutated is None:
                    rc = 'no mutation'
                else:
                    rc = _run_tests(tree, tests, budget, log)
                    if rc == 0:
                        more = [t for t in _confirm_pool(cov, module, tree) if t not in set(tests)]
                        if more:
                            tests, mode = tests + more, 'confirmed'
                            rc = _run_tests(
                                tree, more, 5 * sum(cov['durations'].get(t, 1.0) for t in more) + 300, log
                            )
                    if rc == 4 and 'ERROR collecting' in log.read_text():
                        rc = 2  # the mutant broke an import: pytest says "no collectors" (4)
            finally:
                if mutation is not None:
                    mutation.__exit__(None, None, None)  # the original file back
            if rc in (0, 1, 2, 3, 'signal'):
                outcome = TestOutcome.SURVIVED if rc == 0 else TestOutcome.KILLED
                result = WorkResult(
                    worker_outcome=WorkerOutcome.NORMAL,
                    test_outcome=outcome,
                    output=f'{mode}, {len(tests)} tests, exit {rc}',
                )
                counts['survived' if rc == 0 else 'killed'] += 1
            elif rc == 'timeout':
                result = WorkResult(
                    worker_outcome=WorkerOutcome.ABNORMAL,
                    test_outcome=TestOutcome.KILLED,
                    output=f'timeout: {mode}, {len(tests)} tests, over {budget:.0f} s',
                )
                counts['timeout'] += 1
            else:  # pytest usage error / nothing collected / no mutation: our problem, not a kill
                tail = log.read_text()[-2000:] if log.exists() else ''
                result = WorkResult(
                    worker_outcome=WorkerOutcome.EXCEPTION,
                    test_outcome=TestOutcome.INCOMPETENT,
                    output=f'{rc}\n{tail}',
                )
                counts['incompetent'] += 1
            work_db.set_result(item.job_id, result)
            if rc == 0:
                survivors.append(
                    f'{m.module_path}:{m.start_pos[0]} {m.operator_name.split("/")[-1]} '
                    f'#{m.occurrence} ({mode})'
                )
    return {'counts': counts, 'survivors': survivors, 'mutants_in_module': total}


def wilson(k: int, n: int, z: float = 1.96):
    """95 % Wilson score interval of a binomial proportion k / n (fractions)."""
    if n == 0:
        return 0.0, 1.0
    p, d = k / n, 1 + z * z / n
    centre, half = (p + z * z / (2 * n)) / d, z * (p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5 / d
    return max(0.0, centre - half), min(1.0, centre + half)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--only', default='', help=f'comma-separated subset of: {",".join(MODULES)}')
    ap.add_argument('--workdir', type=Path, default=ROOT / 'out' / 'mutation')
    ap.add_argument(
        '--sample',
        type=int,
        default=0,
        help='run only this many mutants per module, drawn at random (0: all)',
    )
    ap.add_argument('--seed', type=int, default=0, help='seed of --sample')
    ap.add_argument(
        '--reuse-coverage',
        action='store_true',
        help='reuse <workdir>/coverage.json from an earlier run of the same tree',
    )
    args = ap.parse_args(argv)
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # unwind: restore the file, end the run
    names = [n for n in args.only.split(',') if n] or list(MODULES)
    unknown = [n for n in names if n not in MODULES]
    if unknown:
        print(
            f'mutation: unknown module(s) in --only: {unknown}; choose from {list(MODULES)}', file=sys.stderr
        )
        return 2
    workdir = args.workdir.resolve()
    tree = workdir / 'tree'
    _copy_tree(tree)
    os.environ['OMP_NUM_THREADS'] = os.environ['MKL_NUM_THREADS'] = '1'
    os.environ['PYTHONDONTWRITEBYTECODE'] = '1'  # a mutant must never run a stale .pyc
    os.environ['PYTHONPATH'] = str(tree)  # the mutated copy, never the checkout
    cov_file = workdir / 'coverage.json'
    t0 = time.monotonic()
    if args.reuse_coverage and cov_file.exists():
        cov = json.loads(cov_file.read_text())
    else:
        cov = coverage_map(tree, cov_file)
    print(f'coverage map: {len(cov["durations"])} tests ({time.monotonic() - t0:.0f} s)', flush=True)
    import numpy  # noqa: F401 - imported once here, inherited by every forked test run
    import pytest  # noqa: F401
    import torch

    torch.set_num_threads(1)
    gc.freeze()  # the forked runs neither scan nor copy the parent's objects
    results, ok, t_all, n_all = {}, True, time.monotonic(), 0
    for name in names:
        t1 = time.monotonic()
        try:
            r = results[name] = run_module(tree, name, MODULES[name], cov, args.sample, args.seed)
        except subprocess.CalledProcessError as exc:
            print(f'mutation: {name}: {exc}', file=sys.stderr)
            ok = False
            continue
        c = r['counts']
        n_run = c['killed'] + c['timeout'] + c['survived'] + c['incompetent']
        n_all += n_run
        lo, hi = wilson(c['killed'] + c['timeout'], c['killed'] + c['timeout'] + c['survived'])
        print(
            f'{name:18s} of {r["mutants_in_module"]:4d}: killed {c["killed"]:3d} timeout {c["timeout"]:2d} '
            f'survived {c["survived"]:2d} incompetent {c["incompetent"]:2d} fallback {c["fallback"]:2d} '
            f'[{100 * lo:.0f}, {100 * hi:.0f}] % ({time.monotonic() - t1:.0f} s)',
            flush=True,
        )
    minutes = (time.monotonic() - t_all) / 60
    (workdir / 'results.json').write_text(json.dumps(results, indent=1))
    tot = {k: sum(r['counts'][k] for r in results.values()) for k in ('killed', 'timeout', 'survived')}
    caught = tot['killed'] + tot['timeout']
    n = caught + tot['survived']
    lo, hi = wilson(caught, n)
    interval = f' (95 % interval {100 * lo:.1f} to {100 * hi:.1f}, sampled)' if args.sample else ''
    print(
        f'\nmutation score {100 * caught / max(n, 1):.1f} %{interval}: {caught} caught, {tot["survived"]} '
        f'survived; {n_all} mutants in {minutes:.1f} min ({n_all / max(minutes, 1e-9):.1f} per minute)'
    )
    for r in results.values():
        for s in r['survivors']:
            print(f'  survived: {s}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
