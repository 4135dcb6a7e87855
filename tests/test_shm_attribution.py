"""swarm.shm.shm_held_by / shm_left_by: a process's FastDDS files are the lock files it holds
(/proc/locks); after it ends, what of their groups is still there, unlocked, is its leak, except
the segment and mutex of a port that every domain opens (another user's killed process keeps
them)."""

import fcntl
import os

from knode_swarm_ros.nodes.swarm import shm


def _group(root, base):
    for name in (base, f'{base}_el', f'sem.{base}_mutex'):
        (root / name).write_bytes(b'')


def test_held_files_are_the_locked_ones_and_what_stays_after_the_owner_is_the_leak(tmp_path, monkeypatch):
    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    domain = 42
    own_port = f'fastrtps_port{7400 + 250 * domain + 11}'
    for base in ('fastrtps_0123456789abcdef', own_port, 'fastrtps_port7000', 'fastrtps_feedfacefeedface'):
        _group(tmp_path, base)
    handles = [
        open(tmp_path / f'{base}_el', 'ab')
        for base in ('fastrtps_0123456789abcdef', own_port, 'fastrtps_port7000')
    ]
    for fh in handles:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    held = shm.shm_held_by(os.getpid())
    assert held == {'fastrtps_0123456789abcdef_el', f'{own_port}_el', 'fastrtps_port7000_el'}
    assert shm.shm_left_by(held, domain) == []  # all still locked: a live owner
    for fh in handles:
        fh.close()  # the owner "ends" without removing anything
    (tmp_path / 'fastrtps_port7000_el').unlink()  # a clean exit removes the lock, the shared port stays
    segment = 'fastrtps_0123456789abcdef'
    assert shm.shm_left_by(held, domain) == [
        segment,
        f'{segment}_el',
        f'sem.{segment}_mutex',
        own_port,
        f'{own_port}_el',
        f'sem.{own_port}_mutex',
    ]
    assert shm.shm_left_by(held, domain, before=frozenset({own_port, f'sem.{own_port}_mutex'})) == [
        segment,
        f'{segment}_el',
        f'sem.{segment}_mutex',
        f'{own_port}_el',
    ]  # there before: not its
    # without a domain every port counts whole
    assert 'fastrtps_port7000' in shm.shm_left_by(held)


def test_cleanup_removes_the_shared_ports_a_killed_process_left_even_from_before_the_run(
    tmp_path, monkeypatch
):
    """fastrtps_port7000/7001 (opened by every domain's participants) stay behind after any of
    their users is killed, so they are usually there before the launcher's run: the cleanup judges
    them by their lock alone. Before, they were kept because they were not new."""
    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    for name in ('fastrtps_port7000', 'sem.fastrtps_port7000_mutex', 'fastrtps_port7001'):
        (tmp_path / name).write_bytes(b'')  # an earlier run's kill: no lock file left
    _group(tmp_path, 'fastrtps_port7001')  # ... and one a live listener holds
    before = shm.shm_snapshot()
    _group(tmp_path, 'fastrtps_0123456789abcdef')  # this run's killed process: new, unlocked
    with open(tmp_path / 'fastrtps_port7001_el', 'ab') as live:
        fcntl.flock(live, fcntl.LOCK_EX | fcntl.LOCK_NB)
        removed = shm.shm_cleanup(before)
        assert sorted(removed) == [
            'fastrtps_0123456789abcdef',
            'fastrtps_0123456789abcdef_el',
            'fastrtps_port7000',
            'sem.fastrtps_0123456789abcdef_mutex',
            'sem.fastrtps_port7000_mutex',
        ]
        assert sorted(os.listdir(tmp_path)) == [
            'fastrtps_port7001',
            'fastrtps_port7001_el',
            'sem.fastrtps_port7001_mutex',
        ]


def test_lock_holders_name_every_pid_holding_a_lock_file(tmp_path, monkeypatch):
    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    _group(tmp_path, 'fastrtps_port7002')
    _group(tmp_path, 'fastrtps_port7003')
    with open(tmp_path / 'fastrtps_port7002_el', 'ab') as fh:
        fcntl.flock(fh, fcntl.LOCK_SH | fcntl.LOCK_NB)
        assert shm.shm_lock_holders() == {'fastrtps_port7002_el': {os.getpid()}}
    assert shm.shm_lock_holders() == {}  # closed: nobody holds it


def test_a_chaos_round_leaves_out_the_ports_a_process_outside_it_held_too(tmp_path, monkeypatch):
    """A port of every domain (7000...) that a concurrent suite's process held as well may be left
    by that process's kill: not the round's leak. One only the round held still is."""
    import sys

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'bench'))
    import chaos

    monkeypatch.setattr(shm, 'SHM_DIR', tmp_path)
    for base in ('fastrtps_port7002', 'fastrtps_port7003'):
        _group(tmp_path, base)
    ours, theirs = os.getpid(), os.getppid()
    monkeypatch.setattr(
        chaos,
        'shm_lock_holders',
        lambda: {'fastrtps_port7002_el': {ours, theirs}, 'fastrtps_port7003_el': {ours}},
    )
    held, shared = set(), set()
    chaos._sample_locks({ours}, held, shared)
    assert held == {'fastrtps_port7002_el', 'fastrtps_port7003_el'} and shared == {'fastrtps_port7002_el'}
    assert chaos.leftovers(set(), held - shared, domain=3) == ['fastrtps_port7003_el']
