"""Learning any scenario: the hyper-parameters config/train_custom.yaml derives from the data, the
augmentations that follow the scenario, and the whole path CSV -> import_tracks -> train ->
evaluate on a tiny law of our own."""

import json
import os

import numpy as np
import pytest
import torch

from knode_swarm_ros.core import load_policy
from knode_swarm_ros.core.errors import ConfigError
from knode_swarm_ros.core.scenarios import scenario_from_dict
from training.learning.config import PendingConfig, load_config, normalise_config, resolve_config
from training.learning.samples import random_rotations

ROOT = os.path.join(os.path.dirname(__file__), '..')
RECIPE = os.path.join(ROOT, 'config', 'train_custom.yaml')
SPACING, VELOCITY = 0.5, np.array([0.3, 0.4])


def scenario(dims=2, state='position', command='velocity', arena=None):
    return scenario_from_dict(
        dict(name='lattice', dimensions=dims, state=state, command=command, dt=0.1, arena=arena)
    )


def lattice_tracks(frames=5):
    """A 3 x 3 lattice of spacing 0.5 m moving rigidly at (0.3, 0.4) m/s: ``[2, frames, 9, 2]``."""
    grid = SPACING * np.array([[i, j] for i in range(3) for j in range(3)], dtype=float)
    t = 0.1 * np.arange(frames)
    states = grid[None] + t[:, None, None] * VELOCITY
    return np.stack([states, states + 5.0])


def test_derived_hyper_parameters_of_a_lattice_of_known_spacing():
    # the flat encoder's range and k (the set encoder's: tests/test_policy_set_encoder.py)
    pending = load_config(RECIPE, {'policy.encoder': 'flat'})
    assert isinstance(pending, PendingConfig)
    spec = scenario()
    cfg, derived = resolve_config(
        pending, [lattice_tracks()], json.dumps(spec.to_dict(), sort_keys=True), 0.1
    )
    pol = cfg['policy']
    assert pol['d_cr'] == pytest.approx(3 * SPACING)  # 3 x the nearest-neighbour distance
    assert pol['k'] == 9  # the corners are 2 sqrt(2) spacings apart, within d_cr: everyone
    assert pol['command_limit'] == pytest.approx(1.5 * 0.4)  # the largest axis of the velocity
    assert pol['collision_d0'] == pytest.approx(SPACING)  # never closer than the spacing
    # the push at d0 / 2 is half the command limit
    lam = pol['collision_phi'] ** 2
    assert lam * (2 / SPACING - 1 / SPACING) / (SPACING / 2) ** 2 == pytest.approx(0.3, rel=1e-4)
    grid = lattice_tracks()[0, 0]
    offsets = grid[None] - grid[:, None]
    near = (np.linalg.norm(offsets, axis=-1) <= 3 * SPACING) & ~np.eye(9, dtype=bool)
    assert pol['position_scale'] == pytest.approx(np.sqrt(np.mean(offsets[near] ** 2)), rel=1e-5)
    assert pol['velocity_scale'] == 1.0 and pol['wall'] is False or spec.arena is None
    assert cfg['augment']['rotate'] is True  # no arena: rotations are a symmetry
    assert cfg['noise']['variance'] == pytest.approx((0.02 * pol['position_scale']) ** 2, rel=1e-4)
    for name in ('policy.k', 'policy.d_cr', 'policy.command_limit', 'noise.variance'):
        assert derived[name]['value'] is not None and derived[name]['how']


def test_an_explicit_value_wins_over_auto():
    pending = load_config(RECIPE, {'policy.k': 4, 'policy.d_cr': 2.0})
    ref = json.dumps(scenario().to_dict(), sort_keys=True)
    cfg, derived = resolve_config(pending, [lattice_tracks()], ref, 0.1)
    assert cfg['policy']['k'] == 4 and cfg['policy']['d_cr'] == 2.0
    assert 'policy.k' not in derived and 'policy.d_cr' not in derived


def test_double_integrator_in_an_arena_derives_walls_and_no_rotations():
    spec = scenario(3, 'position_velocity', 'acceleration', {'half_width': 4.0})
    pos = lattice_tracks()[:1]
    pos = np.concatenate([pos, np.zeros(pos.shape[:-1] + (1,))], axis=-1) - 1.0
    vel = np.broadcast_to(np.array([0.3, 0.4, 0.0]), pos.shape)
    states = np.concatenate([pos, vel], axis=-1)
    cfg, derived = resolve_config(load_config(RECIPE), [states], json.dumps(spec.to_dict()), 0.1)
    pol = cfg['policy']
    assert cfg['augment']['rotate'] is False and pol['wall'] is True
    # the lattice lies in [-1, 0]^2 x {-1} and drifts inwards in [-4, 4]^3: 3 m from the nearest wall
    assert pol['wall_d0'] == pytest.approx(3.0)
    # a rigid drift needs no acceleration: the limit is the floor, 0.1 x the RMS velocity entry
    assert pol['command_limit'] == pytest.approx(0.1 * np.sqrt((0.09 + 0.16) / 3), rel=1e-4)
    assert pol['velocity_scale'] == pytest.approx(np.sqrt((0.09 + 0.16) / 3), rel=1e-4)
    assert 'policy.wall_d0' in derived


def test_an_augmentation_that_breaks_the_scenario_is_refused_naming_the_field():
    arena = scenario(3, 'position_velocity', 'acceleration', {'half_width': 4.0}).to_dict()
    with pytest.raises(ConfigError, match='augment.rotate.*arena'):
        normalise_config({'scenario': arena, 'augment': {'rotate': True}})
    with pytest.raises(ConfigError, match='augment.velocity_boost.*arena'):
        normalise_config({'scenario': arena, 'augment': {'velocity_boost': 1.0}})
    with pytest.raises(ConfigError, match="augment.velocity_boost.*'state'"):
        normalise_config({'scenario': scenario().to_dict(), 'augment': {'velocity_boost': 1.0}})
    cfg = normalise_config({'scenario': scenario(3).to_dict(), 'augment': {'rotate': True}})
    assert cfg['augment']['rotate'] is True and cfg['policy']['wall'] is False


@pytest.mark.parametrize('dims', [2, 3])
def test_random_rotations_are_rotations(dims):
    R = random_rotations(64, dims, torch.Generator().manual_seed(0))
    eye = torch.eye(dims).expand(64, dims, dims)
    assert torch.allclose(R @ R.transpose(1, 2), eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(R), torch.ones(64), atol=1e-5)


def line_tracks(n, spacing, frames=20):
    """``[1, frames, n, 4]``: n robots on a line ``spacing`` apart, drifting together."""
    z = np.zeros((1, frames, n, 4))
    z[..., 0] = spacing * np.arange(n) + 0.1 * np.arange(frames)[:, None]
    z[..., 2] = 2.0  # the velocity entries
    return z


def test_a_caveat_where_the_data_cannot_tell_a_sum_from_a_mean():
    """One swarm size in which every robot sees every other: the caveat, with the counts; a robot
    beyond d_cr in most frames, or tracks of two sizes: none."""
    from training.learning.derive import size_caveat

    moving = scenario(2, 'position_velocity', 'acceleration')
    caveat = size_caveat([line_tracks(5, 1.0)], moving, d_cr=4.5)  # 4.5 m spans the line
    assert caveat is not None and 'all 4 others within d_cr = 4.5' in caveat and 'in 100 %' in caveat
    assert size_caveat([line_tracks(5, 1.0)], moving, d_cr=3.5) is None  # the ends never see each other
    assert size_caveat([line_tracks(5, 1.0), line_tracks(8, 0.5)], moving, d_cr=4.5) is None


def test_the_study_trains_one_policy_on_tracks_of_two_swarm_sizes(tmp_path):
    """custom_laws --track-robots 6 4: tracks of each size, imported apart, one training on both
    files (its provenance lists both sizes), evaluated at a third size; the results are keyed by
    the folder."""
    from training.studies.custom_laws import main

    out = tmp_path / 'laws'
    argv = ['--laws', 'aggregate2d', '--out', str(out), '--track-robots', '6', '4', '--trajectories', '3']
    argv += ['--eval-robots', '5', '--starts', '2']
    for item in (
        'training.epochs=1',
        'policy.hidden=8',
        'data.val_trajectories=1',
        'selection.trajectories=1',
    ):
        argv += ['--set', item]
    out.mkdir()
    (out / 'results.json').write_text(json.dumps({'an_earlier_law': {'law': 'an_earlier_law'}}))
    assert main(argv) == 0
    folder = out / 'aggregate2d_tracks4+6'
    for n in (4, 6):
        assert np.load(folder / f'tracks_n{n}.npz')['states'].shape[-2] == n
    policy = load_policy(str(folder / 'run' / 'policy.pt'))
    assert policy.meta['provenance']['robots'] == [4, 6]
    assert policy.meta['provenance']['data_file'] == ['tracks_n4.npz', 'tracks_n6.npz']
    assert 'caveats' not in json.loads((folder / 'run' / 'summary.json').read_text())  # two sizes
    results = json.loads((out / 'results.json').read_text())
    assert set(results) == {'an_earlier_law', 'aggregate2d_tracks4+6'}  # an earlier invocation's stays
    assert [r['seed'] for r in results['aggregate2d_tracks4+6']['seeds']] == [0]
    assert results['aggregate2d_tracks4+6']['n5']['robots'] == 5
    assert len(results['aggregate2d_tracks4+6']['n5']['orders']['nn_distance']['per_rollout']['learnt']) == 2


def test_couzin_zones_turn_away_align_and_attract_at_a_bounded_rate():
    """couzin2d on two robots heading +x: a neighbour inside the repulsion zone (ahead, to the
    left) turns the robot right, one in the orientation zone heading +y turns it left, one in the
    attraction zone behind it turns it towards it; never by more than turn_rate x dt, always at
    the set speed. Starts carry unit headings."""
    from training.studies.laws import LAWS, couzin2d, initial_states

    def turn(offset, neighbour_heading=(1.0, 0.0)):
        z = np.array([[[0.0, 0.0, 1.0, 0.0], [*offset, *neighbour_heading]]])
        u = couzin2d(z)[0, 0]
        assert np.linalg.norm(u) == pytest.approx(1.0)
        return np.arctan2(u[1], u[0])

    limit = 2.0 * 0.05
    assert turn((0.3, 0.2)) == pytest.approx(-limit)  # away, as far as the turn rate allows
    assert 0.0 < turn((0.0, 1.0), (0.0, 1.0)) <= limit + 1e-12  # towards the neighbour's heading
    assert turn((-2.0, -0.5)) == pytest.approx(-limit)  # towards a robot behind, to the right
    assert turn((5.0, 5.0)) == pytest.approx(0.0)  # out of every zone: straight on
    h = initial_states(LAWS['couzin2d'], 3, 7, 0)[..., 2:]
    assert np.allclose(np.linalg.norm(h, axis=-1), 1.0)


def test_starlings_heed_their_nearest_whatever_the_distance_and_relax_their_heading():
    """starlings3d, a robot heading +x: a single other robot 100 m away to the +y side (one of its
    k nearest, however far) turns it towards +y; with k = 1 and a second robot nearer at -y, the
    far one is ignored (rank, not range); the speed is set and a step turns by less than
    atan(blend / (1 - blend)), a relaxation towards the wanted direction."""
    from training.studies.laws import starlings3d

    def heading_after(others, k=6):
        z = np.array([[[0.0, 0.0, 0.0, 1.0, 0.0, 0.0]] + [[*o, 1.0, 0.0, 0.0] for o in others]])
        u = starlings3d(z, k=k)[0, 0]
        assert np.linalg.norm(u) == pytest.approx(1.0)
        return u

    far = heading_after([(0.0, 100.0, 0.0)])
    assert far[1] > 0.0 and abs(far[2]) < 1e-12
    ranked = heading_after([(0.0, 100.0, 0.0), (0.0, -3.0, 0.0)], k=1)
    assert ranked[1] < 0.0  # towards the nearer one only
    assert np.arctan2(abs(far[1]), far[0]) <= np.arctan(0.1 / 0.9) + 1e-12


def test_roundabout_robots_follow_the_rooms_field_and_keep_off_each_other():
    """roundabout2d: a lone robot at rest on the ring (2, 0) accelerates anticlockwise (+y) at
    gain x speed; outside the ring it is drawn in, inside pushed out; a second robot within
    1 m adds a push away from it; near a wall the push is off the wall; the command never passes
    3 m/s^2."""
    from training.studies.laws import roundabout2d

    def accel(p, v=(0.0, 0.0), others=()):
        z = np.array([[[*p, *v]] + [[*o, 0.0, 0.0] for o in others]])
        return roundabout2d(z)[0, 0]

    np.testing.assert_allclose(accel((2.0, 0.0)), [0.0, 1.5 * 0.8], atol=1e-12)
    assert accel((2.5, 0.0))[0] < 0.0 < accel((1.5, 0.0))[0]
    pushed = accel((2.0, 0.0), others=[(2.0, 0.5)])
    assert pushed[1] < 1.5 * 0.8 and pushed[0] == pytest.approx(0.0, abs=1e-12)
    assert accel((2.0, 0.0), others=[(2.0, 1.5)])[1] == pytest.approx(1.5 * 0.8)  # out of range
    assert accel((3.8, 0.0), v=(0.0, 0.8))[0] < accel((3.0, 0.0), v=(0.0, 0.8))[0] < 0.0
    assert np.linalg.norm(accel((0.1, 0.0), v=(5.0, 5.0), others=[(0.15, 0.0)])) == pytest.approx(3.0)


def test_fish_in_a_3d_tank_turn_at_a_bounded_rate_away_from_walls_and_neighbours():
    """fish3d_tank, a fish heading +x at 0.8 m/s: alone in mid-tank it goes straight on; a wall
    ahead within 1 m turns it (by the turn limit, 2.5 rad/s x dt, at most), one farther does not; a fish within 0.4 m
    to its left (+y) turns it right (-y); a fish ahead heading +z, in reach, turns it up; the
    speed is always 0.8."""
    from training.studies.laws import fish3d_tank

    def heading(p=(0.0, 0.0, 0.0), others=(), h0=(1.0, 0.0, 0.0)):
        z = np.array([[[*p, *h0]] + [[*o, *h] for o, h in others]])
        u = fish3d_tank(z)[0, 0]
        assert np.linalg.norm(u) == pytest.approx(0.8)
        return u / 0.8

    limit = 2.5 * 0.05
    np.testing.assert_allclose(heading(), [1.0, 0.0, 0.0], atol=1e-12)
    # heading a little to the left (+y) towards the wall at x = 3: it turns on round to the left
    h0 = np.array([np.cos(0.1), np.sin(0.1), 0.0])
    off_wall = heading(p=(2.5, 0.0, 0.0), h0=h0)
    assert np.arccos(np.clip(off_wall @ h0, -1, 1)) == pytest.approx(limit) and off_wall[1] > h0[1]
    np.testing.assert_allclose(heading(p=(1.5, 0.0, 0.0), h0=h0), h0, atol=1e-12)  # the wall out of range
    away = heading(others=[((0.1, 0.3, 0.0), (1.0, 0.0, 0.0))])
    assert away[1] < 0.0 and np.arccos(away[0]) <= limit + 1e-12
    up = heading(others=[((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))])
    assert up[2] > 0.0 and np.arccos(up[0]) <= limit + 1e-12


def test_tank_school_turns_off_a_wall_along_it_and_keeps_its_speed():
    """tank2d (arena half width 3 m, walls felt within 1.2 m): a lone robot in the middle heading
    +x goes straight on; one 0.3 m from the +x wall heading at it turns left (+y: along the wall,
    anticlockwise about the tank), by the most a step allows; one heading -y along that wall
    turns right, off the wall (towards -x); the speed is always the set 1 m/s."""
    from training.studies.laws import tank2d

    def turn(position, heading):
        z = np.array([[[*position, *heading], [0.0, 100.0, 1.0, 0.0]]])  # the other out of reach
        u = tank2d(z)[0, 0]
        assert np.linalg.norm(u) == pytest.approx(1.0)
        return np.arctan2(heading[0] * u[1] - heading[1] * u[0], heading[0] * u[0] + heading[1] * u[1])

    most = 3.0 * 0.05
    assert turn((0.0, 0.0), (1.0, 0.0)) == pytest.approx(0.0)
    assert turn((2.7, 0.0), (1.0, 0.0)) == pytest.approx(most)  # left, as far as a step allows
    assert turn((2.7, 0.0), (0.0, -1.0)) == pytest.approx(-most)  # heading -y: right is -x, off the wall


def test_drones_spring_to_their_spacing_swirl_and_stay_off_the_walls():
    """drones3d_arena: two drones 0.5 m apart along x push apart, 1.0 m apart pull together
    (spacing 0.7 m), beyond reach (1.6 m) nothing; the swirl moves each drone to the left of
    its offset to the neighbours' centroid (about the vertical, clockwise from above); a lone drone
    0.2 m from the +z wall descends; every command within 0.6 m/s."""
    from training.studies.laws import drones3d_arena

    def command(*positions):
        return drones3d_arena(np.array([positions], dtype=float))[0]

    close, apart, far = (
        command((0, 0, 0), (0.5, 0, 0)),
        command((0, 0, 0), (1.0, 0, 0)),
        command((0, 0, 0), (2, 0, 0)),
    )
    assert close[0, 0] < 0.0 < close[1, 0]  # away from each other
    assert apart[0, 0] > 0.0 > apart[1, 0]  # towards each other
    assert np.allclose(far, 0.0)
    assert apart[0, 1] > 0.0 > apart[1, 1]  # the one at x = 0 sees its centroid at +x: left is +y
    assert np.allclose(close[:, 2], 0.0)
    top = command((0, 0, 2.3), (0, 0, -1.0))  # the other beyond reach
    assert top[0, 2] < 0.0 and np.allclose(top[0, :2], 0.0)
    crowd = command(*[(0.05 * i, 0, 0) for i in range(8)])
    assert np.all(np.linalg.norm(crowd, axis=-1) <= 0.6 + 1e-12)


def test_drones_in_open_space_swirl_as_in_the_room_and_anywhere():
    """drones3d: drones3d_arena without its walls: far from any wall the same commands, near where
    the room's wall was none, and the same swarm 100 m away commanded alike (no arena)."""
    from training.studies.laws import drones3d, drones3d_arena

    rng = np.random.default_rng(3)
    middle = rng.uniform(-1.0, 1.0, (2, 6, 3))  # farther than 0.5 m from the room's walls
    np.testing.assert_array_equal(drones3d(middle), drones3d_arena(middle))
    top = np.array([[[0, 0, 2.3], [0, 0, -1.0]]])  # beyond reach of each other
    assert drones3d_arena(top)[0, 0, 2] < 0.0 and np.allclose(drones3d(top), 0.0)  # no wall to leave
    np.testing.assert_allclose(drones3d(middle + 100.0), drones3d(middle), atol=1e-9)


def test_the_law_at_several_sizes_reads_as_the_study_reads_it():
    """law_sizes: the order parameters are the evaluation's on the same starts; the share of
    robot-frames with every other within reach is 1 for a reach beyond the swarm and 0 for one
    below contact; the commands stay within the law's cap (aggregate2d: 1 m/s)."""
    from dataclasses import replace

    from training.assessment.order import order_parameters
    from training.studies.law_sizes import size_rows, size_table
    from training.studies.laws import LAWS, initial_states, simulate

    law = replace(LAWS['aggregate2d'], steps=30)
    far, near = size_rows(law, [4, 6], 2, 5, reach=1e6), size_rows(law, [4, 6], 2, 5, reach=1e-6)
    for row, small, n in zip(far, near, (4, 6)):
        z = simulate(law, initial_states(law, 2, n, 5), 30)
        orders = order_parameters(law.scenario, z, law.scenario.dt, 20)
        assert row['robots'] == n
        assert row['polarisation'] == pytest.approx(
            (np.mean(orders['polarisation']), np.std(orders['polarisation']))
        )
        assert row['nn_distance'][0] == pytest.approx(np.mean(orders['nn_distance']))
        assert row['all_within_reach'] == 1.0 and small['all_within_reach'] == 0.0
        assert 0.0 < row['command_median'] <= row['command_q99'] <= 1.0 + 1e-12
    table = size_table(far, 1e6)
    assert table.count('\n') == 4 and '| 6 |' in table and '100 %' in table


def test_the_whole_path_on_a_tiny_law(tmp_path, capsys):
    """CSV tracks of a tiny law -> import_tracks -> train (1 epoch, train_custom.yaml) -> evaluate."""
    from training.evaluate import main as evaluate_main
    from training.import_tracks import main as import_main
    from training.studies.custom_laws import write_tracks
    from training.studies.laws import LAWS, Law, initial_states, simulate

    base = LAWS['aggregate2d']
    law = Law('tiny', base.scenario, base.command, base.start_radius_per_sqrt_n, 0.0, 30)
    csvs = write_tracks(law, str(tmp_path / 'csv'), 5, 6, seed=3)
    scen = tmp_path / 'tiny.yaml'
    scen.write_text('name: tiny\ndimensions: 2\nstate: position\ncommand: velocity\ndt: 0.05\narena: null\n')
    data = tmp_path / 'tiny.npz'
    assert import_main([*csvs, '--scenario', str(scen), '--out', str(data), '--test-trajectories', '1']) == 0
    from training.train import main as train_main

    run = tmp_path / 'run'
    argv = ['--config', RECIPE, '--data', str(data), '--out', str(run), '--no-progress']
    assert train_main(argv + ['--set', 'training.epochs=1', '--set', 'policy.hidden=8']) == 0
    summary = json.loads((run / 'summary.json').read_text())
    assert summary['derived']['policy.k']['how'].startswith('1 + the smaller of')  # a row-free encoder's k
    assert summary['derived']['policy.symmetric']['value'] is False  # equivariant, no arena
    assert summary['derived']['policy.position_scale']['how'].startswith('the median nearest-neighbour')
    policy = load_policy(str(run / 'policy.pt'))
    assert policy.meta['provenance']['derived']['policy.d_cr']['value'] == policy.d_cr
    assert policy.meta['scenario']['name'] == 'tiny'
    out = tmp_path / 'eval'
    assert evaluate_main(['--policy', str(run / 'policy.pt'), '--data', str(data), '--out', str(out)]) == 0
    results = json.loads((out / 'results.json').read_text())
    for name in (
        'nn_distance',
        'polarisation',
        'rotation_order',
        'speed_median',
        'groups',
        'closest_approach',
    ):
        entry = results['orders'][name]
        assert entry['learnt']['lo'] <= entry['learnt']['mean'] <= entry['learnt']['hi']
        assert np.isfinite(entry['observed']['mean'])
    assert 'polarisation_within_0.10' in results['goal_check']
    assert (out / 'orders.png').stat().st_size > 0
    assert 'Order parameters' in (out / 'summary.md').read_text()
    z0 = initial_states(law, 2, 6, 9)
    assert simulate(law, z0, 3).shape == (2, 4, 6, 2)


def test_a_noisy_recording_of_a_law_is_positions_at_the_rate_with_noise_and_drops(tmp_path):
    """write_noisy_tracks: positions only at the given rate; noise-free it is the law itself, also
    between its steps (the zero-order hold's quadratic steps); the noise has the given std."""
    import csv

    from training.studies.custom_laws import write_noisy_tracks
    from training.studies.laws import LAWS, Law, initial_states, simulate

    base = LAWS['mill2d']
    law = Law('tiny', base.scenario, base.command, base.start_radius_per_sqrt_n, 1.0, 6)
    truth = simulate(law, initial_states(law, 1, 4, 3), law.steps)[0]  # [7, 4, 4]

    def read(noise, jitter=0.0, drop=0.0):
        (path,) = write_noisy_tracks(law, str(tmp_path / str(noise)), 1, 4, 3, noise, 100.0, jitter, drop)
        with open(path) as fh:
            rows = list(csv.reader(fh))
        return rows[0], np.array(rows[1:], dtype=float)

    header, clean = read(0.0)
    assert header == ['t', 'id', 'x', 'y']
    assert len(clean) in (4 * 30, 4 * 31)  # 0.3 s at 100 Hz, 4 robots (the last stamp rounds either way)
    at_steps = clean[np.isclose(clean[:, 0] % law.scenario.dt, 0) | np.isclose(clean[:, 0] % 0.05, 0.05)]
    step = np.rint(at_steps[:, 0] / law.scenario.dt).astype(int)
    robot = (at_steps[:, 1].astype(int) - 10) // 3
    assert np.allclose(at_steps[:, 2:], truth[step, robot, :2], atol=1e-8)
    # between two steps: the position of the zero-order hold's constant acceleration
    mid = clean[np.isclose(clean[:, 0], 0.07) & (clean[:, 1] == 10), 2:][0]
    p, v, a = truth[1, 0, :2], truth[1, 0, 2:], (truth[2, 0, 2:] - truth[1, 0, 2:]) / law.scenario.dt
    assert np.allclose(mid, p + v * 0.02 + 0.5 * a * 0.02**2, atol=1e-8)
    _, noisy = read(0.01, jitter=0.0005, drop=0.2)
    assert 0.6 * len(clean) < len(noisy) < len(clean)
    assert not np.allclose(noisy[:4, 0], 0.0)
    same = np.isclose(clean[:, 0][:, None], np.rint(noisy[:, 0] * 100)[None] / 100) & (
        clean[:, 1][:, None] == noisy[:, 1][None]
    )
    i, j = np.nonzero(same)
    assert 0.007 < np.std(noisy[j, 2:] - clean[i, 2:]) < 0.013
