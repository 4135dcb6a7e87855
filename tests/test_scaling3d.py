"""The 3D scaling study and grid: subswarms, escapes and goals on hand-built swarms with
known answers; the drivers end to end on tiny configurations."""

import json
import os

import matplotlib  # noqa: F401  (a broken install must fail, not skip)
import numpy as np
import pytest
import torch
import yaml

from knode_swarm_ros.core import DEFAULTS, KNODEPolicy, PolicyConfig, export_policy, save_trajectories
from knode_swarm_ros.core.groundtruth import simulate
from training.assessment.boids_stats import group_labels, subgroups
from training.assessment.scaling import (
    escape_events,
    escaped,
    goal_check,
    leaving,
    outside,
    size_metrics,
    subswarm_count,
    summary_lines,
)

BOX = 5.0


def frame(positions, headings=None):
    p = np.asarray(positions, dtype=float)
    h = np.tile([1.0, 0.0, 0.0], (len(p), 1)) if headings is None else np.asarray(headings, dtype=float)
    return np.concatenate([p, h], axis=1)


# ----------------------------------------------------------------------------- subswarms


def test_subswarms_of_hand_built_configurations():
    # Two tight clusters 6 apart, one lone boid: 3 groups, labelled by their lowest-index member.
    z = frame([[0, 0, 0], [6, 0, 0], [0.5, 0, 0], [6, 1, 0], [0, 0, 4]])
    assert subgroups(z[None])[0] == 3
    np.testing.assert_array_equal(group_labels(z[None])[0], [0, 1, 0, 1, 4])
    # The link is "within the radius" (<=): exactly 2.5 apart links, just beyond does not.
    assert subgroups(frame([[0, 0, 0], [2.5, 0, 0]])[None])[0] == 1
    assert subgroups(frame([[0, 0, 0], [2.5 + 1e-6, 0, 0]])[None])[0] == 2
    assert subgroups(frame([[0, 0, 0], [2.5 + 1e-6, 0, 0]])[None], radius=3.0)[0] == 1
    # Every boid alone (lattice spacing 3 > 2.5): n groups.
    lattice = np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(4)], float) * 3.0
    assert subgroups(frame(lattice)[None])[0] == 64


def test_subswarms_close_long_chains_in_any_order():
    # 90 boids on a chain with links of 2.0: ends 178 apart, one group whatever the numbering;
    # cutting one link gives two groups.
    rng = np.random.default_rng(0)
    chain = np.stack([np.arange(90) * 2.0, np.zeros(90), np.zeros(90)], axis=1)
    order = rng.permutation(90)
    assert subgroups(frame(chain[order])[None])[0] == 1
    cut = chain.copy()
    cut[40:, 0] += 1.0
    assert subgroups(frame(cut[order])[None])[0] == 2
    labels = group_labels(frame(cut[order])[None])[0]
    assert len(set(labels[order < 40])) == 1 and len(set(labels[order >= 40])) == 1


def test_subswarm_count_is_the_mean_over_the_last_frames():
    one = frame([[0, 0, 0], [1, 0, 0], [2, 0, 0]])
    three = frame([[0, 0, 0], [3, 0, 0], [-3, 0, 0]])
    run = np.stack([three, three, one, three])[None]  # [1, 4, 3, 6]
    np.testing.assert_allclose(subswarm_count(run, last=2), [2.0])
    np.testing.assert_allclose(subswarm_count(run, last=4), [2.5])


# ----------------------------------------------------------------------------- escapes


def test_escapes_and_their_diagnostics():
    dt = 0.1
    T, n = 5, 3
    run = np.zeros((T, n, 6))
    run[..., 3] = 1.0
    run[:, 0, :3] = [0.0, 0.0, 4.0]
    run[:, 1, :3] = [0.0, 0.0, 4.5]  # 0.5 from boid 1: its only neighbour within d_cr 1
    run[:, 2, :3] = [-4.0, 0.0, 0.0]
    run[2, 1, 2], run[3, 1, 2] = 5.2, 5.0 + 5e-10  # out at frame 2, back (within tolerance) at frame 3
    run[4, 2, 0] = -5.3  # boid 2 leaves through -x at the last frame
    pred = run[None]
    np.testing.assert_array_equal(outside(pred, BOX)[0, :, 1], [False, False, True, False, False])
    np.testing.assert_array_equal(escaped(pred, BOX), [[False, True, True]])
    events = {e['boid']: e for e in escape_events(pred, BOX, d_cr=1.0, dt=dt)}
    assert sorted(events) == [1, 2]
    e1, e2 = events[1], events[2]
    assert (e1['frame'], e1['wall'], e1['neighbours'], e1['group'], e1['inside_at_end']) == (
        2,
        '+z',
        1,
        2,
        True,
    )
    assert e1['outward_speed'] == pytest.approx((5.2 - 4.5) / dt)
    assert (e2['frame'], e2['wall'], e2['neighbours'], e2['group'], e2['inside_at_end']) == (
        4,
        '-x',
        0,
        1,
        False,
    )
    assert e2['t'] == pytest.approx(0.4)


def test_leaving_means_inside_then_outside():
    # One start, 6 frames, 5 boids, hand-built x coordinates (y = z = 0); the cube is [-5, 5]^3.
    x = np.array(
        [
            [0.0, 5.5, 5.5, 6.0, 0.0],  # frame 0: boids 1-3 spawned outside
            [0.0, 5.4, 4.9, 6.0, 0.0],
            [0.0, 5.3, 5.2, 6.0, 0.0],  # boid 2: in at frame 1, out again at 2 -> leaves
            [0.0, 5.2, 4.0, 5.0, 5.1],  # boid 3 gets in at 3 and stays; boid 4 leaves at 3
            [0.0, 5.1, 4.0, 4.0, 4.0],  # boid 4 back in
            [0.0, 5.0 + 5e-10, 4.0, 4.0, 4.0],
        ]
    )  # boid 1 on the wall within tolerance: inside, never left
    states = np.zeros((1, 6, 5, 6))
    states[0, :, :, 0] = x
    left = leaving(states, BOX)[0]  # [T, n]
    expected = np.zeros((6, 5), dtype=bool)
    expected[2, 2] = expected[3, 4] = True
    np.testing.assert_array_equal(left, expected)
    assert not left[0].any()  # frame 0 never counts
    np.testing.assert_array_equal(escaped(states, BOX), [[False, False, True, False, True]])
    # A boid outside in every frame has never been inside: it has not left.
    assert not escaped(np.full((1, 4, 1, 6), 7.0), BOX).any()
    events = escape_events(states, BOX, d_cr=1.0, dt=0.1)
    assert [(e['boid'], e['frame'], e['wall'], e['inside_at_end']) for e in events] == [
        (2, 2, '+x', True),
        (4, 3, '+x', True),
    ]
    # The per-start goal count: boids spawned outside do not fail "no boid leaves", a boid leaving does.
    calm = states.copy()
    calm[..., 2, 0], calm[..., 4, 0] = 4.0, 0.0  # boids 2 and 4 stay inside
    m = size_metrics(np.concatenate([calm, states]), np.concatenate([calm, calm]), dt=0.1)
    assert m['no_boid_leaves'] == [True, False] and m['spawned_outside'] == [True, True]
    assert m['stays_inside'] == [False, False]  # the stricter every-frame test, kept for reference
    np.testing.assert_allclose(m['escaped'], [0.0, 2 / 5])
    np.testing.assert_allclose(m['truth_escaped'], [0.0, 0.0])


def test_goal_check_thresholds():
    def row(n, rel, inside):
        return {'robots': n, 'amd_rel_error': rel, 'starts_inside': inside}

    check = goal_check([row(10, 0.9, 0), row(50, 0.15, 14), row(90, -0.151, 13)], ics=15)
    assert check['50: amd_within_15%'] and check['50: inside>=14/15']
    assert not check['90: amd_within_15%'] and not check['90: inside>=14/15']
    assert not any(key.startswith('10:') for key in check)
    assert goal_check([row(50, 0.0, 2)], ics=2)['50: inside>=2/2']  # 14/15 of 2 starts rounds up to 2
    # Starts with a boid outside in the first frame are reported (information), not counted as exits.
    check = goal_check([row(50, 0.0, 15), {**row(90, 0.0, 15), 'starts_spawned_outside': 2}], ics=15)
    assert check['90: spawn_outside'] == 2 and check['90: inside>=14/15'] and '50: spawn_outside' not in check


# ----------------------------------------------------------------------------- drivers


def _tiny_policy(tmp_path):
    torch.manual_seed(0)
    policy = KNODEPolicy(PolicyConfig('boids3d', **{**DEFAULTS['boids3d'], 'hidden': 8}))
    path = tmp_path / 'p.pt'
    export_policy(policy, path, policy.metadata())
    return str(path)


def test_scaling_driver_tiny_configuration(tmp_path):
    from training.evaluate import main

    out = tmp_path / 'scaling'
    args = [
        '--policy',
        _tiny_policy(tmp_path),
        '--out',
        str(out),
        '--scaling',
        '--sizes',
        '6',
        '50',
        '--ics',
        '2',
        '--scaling-steps',
        '6',
        '--preset',
        'published',
    ]
    assert main(args) == 0
    s = json.loads((out / 'results.json').read_text())['scaling']
    assert (s['sizes'], s['ics'], s['steps'], s['preset']) == ([6, 50], 2, 6, 'published')
    assert [r['robots'] for r in s['rows']] == [6, 50]
    for r in s['rows']:
        for key in (
            'amd_final',
            'truth_amd_final',
            'pod_kld',
            'escaped',
            'truth_escaped',
            'subswarms',
            'truth_subswarms',
        ):
            assert len(r['per_start'][key]) == 2 and set(r[key]) >= {'mean', 'median', 'q1', 'q3'}, key
        assert 0 <= r['starts_inside'] <= 2 and np.isfinite(r['amd_rel_error'])
        assert r['truth_starts_inside'] == 2  # the boids never leave their cube
    assert set(s['escape_events']) == {'6', '50'} and set(s['curves']) == {'6', '50'}
    assert len(s['curves']['50']['t']) == 7 and set(s['curves']['50']) == {'t', 'subswarms', 'escaped', 'amd'}
    assert set(s['goal_check']) == {
        '50: amd_within_15%',
        '50: amd_rel_error',
        '50: inside>=2/2',
        '50: starts_inside',
        '50: spawn_outside',
    }
    for name in ('scaling.png', 'departures.png', 'summary.md'):
        assert (out / name).stat().st_size > 0, name
    text = (out / 'summary.md').read_text()
    assert '| 50 |' in text and 'subswarms truth' in text and '50: amd_within_15%' in text
    assert summary_lines(s)[0].startswith('## Scaling (2 starts per size, 6 steps')

    # Sizes run as separate processes merge back into the same study.
    from training.studies.scaling3d import main as merge_main

    for i, n in enumerate((6, 50)):
        part = {
            **s,
            'rows': [s['rows'][i]],
            'sizes': [n],
            'escape_events': {str(n): s['escape_events'][str(n)]},
            'curves': {str(n): s['curves'][str(n)]},
        }
        if n == 6:
            part['example'] = {**s['example'], 'robots': 6}
        os.makedirs(tmp_path / f'part{n}')
        (tmp_path / f'part{n}' / 'results.json').write_text(json.dumps({'policy': 'p.pt', 'scaling': part}))
    parts = [str(tmp_path / f'part{n}' / 'results.json') for n in (50, 6)]
    assert merge_main(['--merge', *parts, '--out', str(tmp_path / 'merged')]) == 0
    m = json.loads((tmp_path / 'merged' / 'results.json').read_text())['scaling']
    assert m['sizes'] == [6, 50] and m['rows'] == s['rows'] and m['goal_check'] == s['goal_check']
    assert m['example'] == s['example'] and (tmp_path / 'merged' / 'departures.png').stat().st_size > 0
    assert merge_main(['--merge', parts[0], parts[0], '--out', str(tmp_path / 'bad')]) == 2  # a size twice


def test_scaling_driver_bad_arguments(tmp_path, capsys):
    from training.evaluate import main

    pol = _tiny_policy(tmp_path)
    base = ['--policy', pol, '--out', str(tmp_path / 'o'), '--scaling', '--sizes', '6', '--ics', '1']
    assert main(base + ['--scaling-steps', '3', '--preset', 'nope']) == 2
    assert "--preset 'nope'" in capsys.readouterr().err
    assert main(base) == 2  # no --data: the length must be given
    assert '--scaling-steps' in capsys.readouterr().err
    assert main(base + ['--scaling-steps', '0']) == 2
    assert not os.path.exists(tmp_path / 'o' / 'results.json')


def test_grid_boids3d_rollouts_per_start_and_reevaluation(tmp_path):
    from training.assessment.scores import perturbed_starts
    from training.grid import main as grid_main

    z0 = simulate('boids3d', 2, 5, 1, seed=3, progress=False)[:, 0]
    z = perturbed_starts(z0, 3, 1e-3, 3)
    assert z.shape == (6, 5, 6)
    np.testing.assert_array_equal(z[0::3], z0)  # copy 0 of every start is the start
    np.testing.assert_array_equal(z[1::3, :, 3:], z0[:, :, 3:])  # headings untouched
    assert 1e-5 < np.abs(z[1::3, :, :3] - z0[:, :, :3]).max() < 1e-2

    states = simulate('boids3d', 3, 5, 12, seed=1, progress=False)
    data = tmp_path / 'd.npz'
    save_trajectories(data, states, 1 / 60, 'boids3d', {'split': {'train': [0, 1], 'test': [2]}})
    raw = {
        'scenario': 'boids3d',
        'seed': 0,
        'policy': {'hidden': 8},
        'data': {'val_trajectories': 1},
        'training': {'epochs': 1, 'batch_size': 64, 'threads': 1},
        'selection': {'every': 0},
    }
    cfg = tmp_path / 'cfg.yaml'
    cfg.write_text(yaml.safe_dump(raw))
    out = tmp_path / 'grid'
    args = [
        '--config',
        str(cfg),
        '--data',
        str(data),
        '--out',
        str(out),
        '--d-cr',
        '2',
        '--k',
        '3',
        '--trajectories',
        '1',
    ]
    assert grid_main(args) == 0
    cell = json.loads((out / 'dcr2_k3' / 'cell.json').read_text())
    assert (
        len(cell['amd_final']) == 1
        and cell['evaluation']['rollouts'] == 1
        and cell['training']['epochs'] == 1
    )
    trained = os.path.getmtime(out / 'dcr2_k3' / 'policy.pt')
    assert grid_main(args + ['--rollouts', '3']) == 0  # evaluated again, not trained again
    assert os.path.getmtime(out / 'dcr2_k3' / 'policy.pt') == trained
    cell = json.loads((out / 'dcr2_k3' / 'cell.json').read_text())
    assert cell['evaluation'] == {'trajectories': 1, 'rollouts': 3, 'perturb': 1e-3}
    for key in ('amd_final', 'pod_kld', 'escaped', 'subswarms', 'stays_inside'):
        assert len(cell[key]) == 3, key
    assert len(set(cell['truth_amd_final'])) == 1  # one ground truth per start
    results = json.loads((out / 'results.json').read_text())
    for key in ('amd_final_mean', 'amd_final_median', 'escaped_mean', 'left_cube_mean', 'pod_kld_median'):
        assert np.isfinite(results['tables'][key][0][0]), key
    assert results['tables']['amd_final_mean'][0][0] == pytest.approx(np.mean(cell['amd_final']))
    assert (out / 'heatmap_amd_final_median.png').is_file() and (out / 'heatmap_left_cube_mean.png').is_file()
    assert grid_main(args + ['--rollouts', '0']) == 2


def test_scaling_study_known_answers_with_a_scripted_rollout(tmp_path):
    """The study's pipeline against known answers: a "policy" that replays the ground truth scores
    amd error 0, POD-KLD 0 and the truth's subswarms; one that pushes boid 0 of start 1 through +y
    from frame 3 on is counted as exactly one escape, in one start, through +y."""
    from types import SimpleNamespace

    from knode_swarm_ros.core.groundtruth import simulate as sim
    from training.assessment.scaling import scaling_study

    policy = SimpleNamespace(scenario='boids3d', dt=1 / 60, d_cr=2.0)
    sizes, ics, steps, seed = (5, 12), 3, 8, 7
    os.makedirs(tmp_path / 'same'), os.makedirs(tmp_path / 'out')

    def replay(pol, z0, n_steps):
        truth = sim(
            'boids3d', ics, z0.shape[1], n_steps + 1, seed + z0.shape[1], preset='published', progress=False
        )
        np.testing.assert_array_equal(truth[:, 0], z0)  # the rollout starts from the truth's first frame
        return truth

    s = scaling_study(
        policy,
        str(tmp_path / 'same'),
        sizes,
        ics,
        steps,
        seed,
        preset='published',
        log=lambda *a: None,
        rollout_fn=replay,
    )
    for r in s['rows']:
        assert r['amd_rel_error'] == 0.0 and r['starts_inside'] == r['truth_starts_inside'] == ics
        np.testing.assert_allclose(r['per_start']['pod_kld'], 0.0, atol=1e-12)
        assert r['per_start']['subswarms'] == r['per_start']['truth_subswarms']
        assert r['per_start']['escaped'] == [0.0] * ics
    assert s['escape_events'] == {'5': [], '12': []}

    def push_out(pol, z0, n_steps):
        z = replay(pol, z0, n_steps).copy()
        z[1, 3:, 0, 1] = 5.5  # start 1, boid 0, y beyond the +5 wall
        return z

    s = scaling_study(
        policy,
        str(tmp_path / 'out'),
        sizes,
        ics,
        steps,
        seed,
        preset='published',
        log=lambda *a: None,
        rollout_fn=push_out,
    )
    for r, n in zip(s['rows'], sizes):
        assert r['starts_inside'] == ics - 1 and r['truth_starts_inside'] == ics
        np.testing.assert_allclose(r['per_start']['escaped'], [0.0, 1.0 / n, 0.0])
        (e,) = s['escape_events'][str(n)]
        assert (e['start'], e['boid'], e['frame'], e['wall'], e['inside_at_end']) == (1, 0, 3, '+y', False)
        assert s['curves'][str(n)]['escaped']['prediction'][-1] == pytest.approx(1.0 / (ics * n))
    assert s['goal_check'] == {}  # no goal size among 5, 12
    assert (tmp_path / 'out' / 'scaling.png').stat().st_size > 0


def test_crowding_on_a_hand_built_frame(tmp_path, capsys):
    from training.studies.crowding import crowding
    from training.studies.crowding import main as crowding_main

    # Boid 0 at the origin with 6 others at 1.0, 1.5, 1.9 (x2), 2.0 and 3.0: 5 within d_cr 2 (<=).
    pts = [[0, 0, 0], [1.0, 0, 0], [0, 1.5, 0], [0, 0, 1.9], [-1.9, 0, 0], [0, -2.0, 0], [0, 0, -3.0]]
    c = crowding(frame(pts)[None], d_cr=2.0, k=6)
    d = np.linalg.norm(np.asarray(pts, float)[:, None] - np.asarray(pts, float)[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    within = (d <= 2.0).sum(axis=1)
    assert within[0] == 5 and c['in_range_mean'] == pytest.approx(within.mean())
    assert c['unseen_share'] == pytest.approx(np.mean(within > 5))
    assert c['nn_median'] == pytest.approx(np.median(d.min(axis=1)))
    assert crowding(frame(pts)[None], d_cr=2.0, k=5)['unseen_share'] >= 1 / 7  # boid 0 now misses one
    ex = {'robots': 7, 'start': 0, 'prediction': frame(pts).tolist(), 'ground truth': frame(pts).tolist()}
    (tmp_path / 'r.json').write_text(json.dumps({'scaling': {'example': ex}}))
    assert crowding_main([str(tmp_path / 'r.json')]) == 0
    assert capsys.readouterr().out.count('7 boids, start 0') == 2
    assert crowding_main([str(tmp_path / 'missing.json')]) == 2


def test_knowledge_variant_changes_only_the_knowledge_settings(tmp_path, capsys):
    from knode_swarm_ros.core import load_policy
    from training.studies.knowledge_variant import main as variant_main

    pol = _tiny_policy(tmp_path)
    original = load_policy(pol)
    out = tmp_path / 'v.pt'
    assert variant_main([pol, '--set', 'collision_d0=0.5', '--set', 'wall=false', '--out', str(out)]) == 0
    v = load_policy(str(out))
    assert v.meta['config']['collision_d0'] == 0.5 and v.meta['config']['wall'] is False
    assert v.meta['provenance']['knowledge_variant']['changes'] == {'collision_d0': 0.5, 'wall': False}
    assert set(v.meta['provenance']['knowledge_variant']) >= {'of', 'git_commit', 'git_tree_clean'}
    # Known answer: the same parameters in a policy built with those settings.
    torch.manual_seed(0)
    ref = KNODEPolicy(
        PolicyConfig('boids3d', **{**DEFAULTS['boids3d'], 'hidden': 8, 'collision_d0': 0.5, 'wall': False})
    )
    ref.load_state_dict(original.module.state_dict())
    Y = torch.randn(64, 6, 6) * 1.2
    Y[:, 0, :3] = 4.7  # near three walls: the wall term would act
    mask = torch.ones(64, 6)
    with torch.no_grad():
        np.testing.assert_allclose(v(Y, mask), ref(Y, mask).numpy(), atol=1e-6)
    assert np.abs(v(Y, mask) - original(Y, mask)).max() > 1e-3
    for bad in (['--set', 'collision_d0=0'], ['--set', 'hidden=4'], ['--set', 'wall=maybe'], []):
        assert variant_main([pol, *bad, '--out', str(tmp_path / 'bad.pt')]) == 2, bad
    assert not (tmp_path / 'bad.pt').exists()
    assert 'collision_d0' in capsys.readouterr().err


def test_knowledge_variant_switches_the_potential_form(tmp_path, capsys):
    # the same network and gains with the other avoidance potential (an ablation of the form alone)
    from knode_swarm_ros.core import load_policy
    from training.studies.knowledge_variant import main as variant_main

    pol = _tiny_policy(tmp_path)
    original = load_policy(pol)
    assert original.meta['config']['potential'] == 'paper'
    out = tmp_path / 'c.pt'
    assert variant_main([pol, '--set', 'potential=continuous', '--out', str(out)]) == 0
    v = load_policy(str(out))
    assert v.meta['config']['potential'] == 'continuous'
    ref = KNODEPolicy(
        PolicyConfig('boids3d', **{**DEFAULTS['boids3d'], 'hidden': 8, 'potential': 'continuous'})
    )
    ref.load_state_dict(original.module.state_dict())
    torch.manual_seed(1)
    Y = torch.randn(64, 6, 6) * 0.6
    Y[:, 0, :3] = 4.5
    mask = torch.ones(64, 6)
    with torch.no_grad():
        np.testing.assert_allclose(v(Y, mask), ref(Y, mask).numpy(), atol=1e-6)
    assert np.abs(v(Y, mask) - original(Y, mask)).max() > 1e-3
    assert variant_main([pol, '--set', 'potential=smooth', '--out', str(tmp_path / 'bad.pt')]) == 2
    assert not (tmp_path / 'bad.pt').exists()
    assert 'potential' in capsys.readouterr().err
