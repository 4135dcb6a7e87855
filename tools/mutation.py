"""Mutation testing of the core and the ROS-free node logic with cosmic-ray (issue 18).

    python tools/mutation.py [--only knowledge,network] [--workdir out/mutation]

For each module of :data:`PLAN` a cosmic-ray session mutates that module one mutation at a
time and runs the fast tests that cover it (``pytest -x``, no ROS processes); a mutant
*survives* when those tests still pass. The run happens in a copy of the repository under
``--workdir`` (cosmic-ray edits the files it mutates), so the checkout is never touched. At the
end it prints, per module and in total, killed / survived / timed out / incompetent and the
score ``killed / (killed + survived)``, then every survivor as ``file:line operator``.
``--sample N`` runs a seeded random N mutants per module instead (a cheaper estimate,
printed with its 95 % binomial interval). Exit status: 0 when every module ran, 1 otherwise (a score below the goal is reported, not
an error: see docs/testing.md).

Why cosmic-ray and not mutmut: mutmut 3 replaces every function by a trampoline, which
TorchScript cannot compile, and the policy's maths is exported as TorchScript.

Operators left out (``EXCLUDED``): bitwise/shift replacements of arithmetic operators and
``is``/``is not`` swaps of value comparisons. On the float arrays and tensors of this code
they raise TypeError at once, so they cost a full pytest start each and tell nothing.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# module -> the fast tests that exercise it (first failure stops the run: -x).
CORE_TESTS = ['tests/test_knowledge.py', 'tests/test_policy.py', 'tests/test_network.py',
              'tests/test_delay_buffer.py', 'tests/test_metrics.py', 'tests/test_rollout.py',
              'tests/test_trajectory_io.py']
LOGIC_TESTS = ['tests/test_nodes_logic.py', 'tests/test_agent_logic_edges.py']
PLAN = {
    'knowledge': ('knode_swarm_ros/core/knowledge.py', ['tests/test_knowledge.py', 'tests/test_policy.py']),
    'network': ('knode_swarm_ros/core/network.py', ['tests/test_network.py', 'tests/test_rollout.py']),
    'policy': ('knode_swarm_ros/core/policy.py', ['tests/test_policy.py', 'tests/test_knowledge.py']),
    'policy_io': ('knode_swarm_ros/core/policy_io.py', ['tests/test_policy.py']),
    'delay_buffer': ('knode_swarm_ros/core/delay_buffer.py', ['tests/test_delay_buffer.py'] + LOGIC_TESTS),
    'metrics': ('knode_swarm_ros/core/metrics.py', ['tests/test_metrics.py']),
    'scenarios': ('knode_swarm_ros/core/scenarios.py', CORE_TESTS),
    'trajectory': ('knode_swarm_ros/core/trajectory.py', ['tests/test_trajectory_io.py']),
    'rollout': ('knode_swarm_ros/core/rollout.py', ['tests/test_rollout.py', 'tests/test_network.py']),
    'core_init': ('knode_swarm_ros/core/__init__.py', CORE_TESTS),
    'groundtruth_init': ('knode_swarm_ros/core/groundtruth/__init__.py', ['tests/test_groundtruth.py']),
    'tanner': ('knode_swarm_ros/core/groundtruth/tanner.py', ['tests/test_groundtruth.py']),
    'boids': ('knode_swarm_ros/core/groundtruth/boids.py', ['tests/test_groundtruth.py']),
    'agent_logic': ('knode_swarm_ros/nodes/agent_logic.py', LOGIC_TESTS),
    'simulator_logic': ('knode_swarm_ros/nodes/simulator_logic.py', LOGIC_TESTS),
    'recorder_logic': ('knode_swarm_ros/nodes/recorder_logic.py', LOGIC_TESTS),
}
EXCLUDED = [r'core/ReplaceBinaryOperator_\w+_(BitOr|BitAnd|BitXor|LShift|RShift)$',
            r'core/ReplaceComparisonOperator_(Eq|NotEq|Lt|LtE|Gt|GtE)_(Is|IsNot)$']


def _copy_tree(dest: Path) -> None:
    """Tracked and untracked-but-not-ignored files of the checkout, copied to ``dest``."""
    files = subprocess.run(['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
                           cwd=ROOT, check=True, capture_output=True).stdout.split(b'\0')
    if dest.exists():
        shutil.rmtree(dest)
    for name in filter(None, files):
        src = ROOT / name.decode()
        if src.is_file():
            (dest / name.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name.decode())


def _config(tree: Path, module: str, tests, timeout: float) -> str:
    test_files = ' '.join(t for t in tests if (tree / t).exists())
    cmd = f'{sys.executable} -m pytest -x -q -p no:cacheprovider -m "not ros" {test_files}'
    return '\n'.join([
        '[cosmic-ray]', f'module-path = "{module}"', f'timeout = {timeout}', 'excluded-modules = []',
        f'test-command = {json.dumps(cmd)}', '',
        '[cosmic-ray.distributor]', 'name = "local"', '',
        '[cosmic-ray.filters.operators-filter]', f'exclude-operators = {json.dumps(EXCLUDED)}', ''])


def _tool(name: str) -> str:
    return str(Path(sys.executable).with_name(name))


def _sample(db: Path, size: int, seed: int) -> None:
    """Keep a seeded random ``size`` of the pending mutants; mark the rest skipped."""
    import random

    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import WorkResult, WorkerOutcome
    with use_db(str(db), WorkDB.Mode.open) as work_db:
        pending = sorted(item.job_id for item in work_db.pending_work_items)
        keep = set(random.Random(seed).sample(pending, min(size, len(pending))))
        for job_id in pending:
            if job_id not in keep:
                work_db.set_result(job_id, WorkResult(output='not in the sample',
                                                      worker_outcome=WorkerOutcome.SKIPPED))


def run_module(tree: Path, name: str, module: str, tests, timeout: float, sample: int = 0,
               seed: int = 0) -> dict:
    cfg, db = tree / f'mutation_{name}.toml', tree / f'mutation_{name}.sqlite'
    cfg.write_text(_config(tree, module, tests, timeout))
    db.unlink(missing_ok=True)
    run = lambda *a: subprocess.run(a, cwd=tree, check=True, stdout=subprocess.DEVNULL)  # noqa: E731
    run(_tool('cosmic-ray'), 'init', str(cfg), str(db))
    run(_tool('cr-filter-operators'), str(db), str(cfg))
    run(_tool('cr-filter-pragma'), str(db))
    if sample:
        _sample(db, sample, seed)
    run(_tool('cosmic-ray'), 'exec', str(cfg), str(db))
    dump = subprocess.run([_tool('cosmic-ray'), 'dump', str(db)], cwd=tree, check=True,
                          capture_output=True, text=True).stdout
    counts = {'killed': 0, 'survived': 0, 'timeout': 0, 'incompetent': 0, 'skipped': 0}
    survivors = []
    for line in dump.splitlines():
        item, result = json.loads(line)
        if result is None:
            continue
        if result['worker_outcome'] == 'skipped':
            counts['skipped'] += 1
        elif result['worker_outcome'] in ('exception', 'abnormal'):
            counts['incompetent'] += 1
        elif result['test_outcome'] == 'killed':
            counts['timeout' if result['worker_outcome'] == 'timeout' else 'killed'] += 1
        elif result['test_outcome'] == 'incompetent':
            counts['incompetent'] += 1
        else:
            m = item['mutations'][0]
            counts['survived'] += 1
            survivors.append(f"{m['module_path']}:{m['start_pos'][0]} {m['operator_name'].split('/')[-1]}"
                             f" #{m['occurrence']}")
    return {'counts': counts, 'survivors': survivors}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--only', default='', help=f'comma-separated subset of: {",".join(PLAN)}')
    ap.add_argument('--workdir', type=Path, default=ROOT / 'out' / 'mutation')
    ap.add_argument('--timeout', type=float, default=300.0, help='seconds per mutant (default 300)')
    ap.add_argument('--sample', type=int, default=0,
                    help='run only this many mutants per module, drawn at random (0: all)')
    ap.add_argument('--seed', type=int, default=0, help='seed of --sample')
    args = ap.parse_args(argv)
    names = [n for n in args.only.split(',') if n] or list(PLAN)
    unknown = [n for n in names if n not in PLAN]
    if unknown:
        print(f'mutation: unknown module(s) in --only: {unknown}; choose from {list(PLAN)}', file=sys.stderr)
        return 2
    tree = args.workdir.resolve() / 'tree'
    _copy_tree(tree)
    os.environ.setdefault('OMP_NUM_THREADS', '1')
    os.environ['PYTHONPATH'] = str(tree)  # the mutated copy, never the checkout
    results, ok = {}, True
    for name in names:
        module, tests = PLAN[name]
        t0 = time.monotonic()
        try:
            results[name] = run_module(tree, name, module, tests, args.timeout, args.sample, args.seed)
        except subprocess.CalledProcessError as exc:
            print(f'mutation: {name}: {exc}', file=sys.stderr)
            ok = False
            continue
        c = results[name]['counts']
        print(f'{name:18s} killed {c["killed"]:4d} timeout {c["timeout"]:3d} survived {c["survived"]:3d} '
              f'incompetent {c["incompetent"]:3d} ({time.monotonic() - t0:.0f} s)', flush=True)
    (args.workdir / 'results.json').write_text(json.dumps(results, indent=1))
    tot = {k: sum(r['counts'][k] for r in results.values()) for k in ('killed', 'timeout', 'survived')}
    caught = tot['killed'] + tot['timeout']
    score = caught / max(caught + tot['survived'], 1)
    n = caught + tot['survived']
    spread = f' +- {100 * 1.96 * (score * (1 - score) / max(n, 1)) ** 0.5:.1f} (95 %, sampled)' if args.sample else ''
    print(f'\nmutation score {100 * score:.1f} %{spread} ({caught} caught, {tot["survived"]} survived) '
          f'over {", ".join(results)}')
    for name, r in results.items():
        for s in r['survivors']:
            print(f'  survived: {s}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
