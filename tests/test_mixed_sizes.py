"""Training on several data files with swarms of different sizes, and provenance
(repository-relative data paths, the commit of the code, the rewrite of shipped metadata)."""

import os
import shutil

import numpy as np
import torch
import yaml
from test_training import _config, _teacher_data, spy_on_selection_rollouts

from knode_swarm_ros.core import load_policy, load_runtime, save_trajectories, shipped_policy_path
from training.learning.records import data_reference
from training.learning.samples import make_samples
from training.learning.trainer import Trainer
from training.studies.provenance import main as provenance_main
from training.train import main as train_main

torch.set_num_threads(1)


def _two_sizes(tmp_path):
    """Teacher data of the same linear controller on 5 and 9 robots, in two files."""
    small, linear = _teacher_data(tmp_path, steps=50, trajectories=4, n=5, seed=0)
    os.rename(small, tmp_path / 'n5.npz')
    big, _ = _teacher_data(tmp_path, steps=50, trajectories=4, n=9, seed=1)
    os.rename(big, tmp_path / 'n9.npz')
    return [str(tmp_path / 'n5.npz'), str(tmp_path / 'n9.npz')], linear


def test_mixed_sizes_train_one_policy_on_the_samples_of_both(tmp_path):
    paths, linear = _two_sizes(tmp_path)
    _, cfg = _config(
        tmp_path,
        policy={'collision': False, 'hidden': 32},
        noise={'mode': 'none'},
        training={'epochs': 40, 'batch_size': 128, 'lr': 0.01, 'lr_min': 0.001},
        selection={'every': 0},
    )
    trainer = Trainer(cfg, paths, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    # every file's train trajectories (3 - 1 validation = 2 each) give 49 frames x n robots of samples
    assert len(trainer.train) + trainer.dropped == 2 * 49 * 5 + 2 * 49 * 9
    trainer.run()
    policy = load_policy(tmp_path / 'run' / 'policy.pt')
    prov = policy.meta['provenance']
    assert prov['robots'] == [5, 9] and prov['data_file'] == ['n5.npz', 'n9.npz']
    assert prov['train_trajectories'] == [[0, 1], [0, 1]] and prov['val_trajectories'] == [[2], [2]]
    # the one policy fits the teacher on both sizes' neighbour matrices (each file's train trajectories)
    from knode_swarm_ros.core import load_trajectories

    for path in paths:
        s = make_samples(load_trajectories(path).states[:2], trainer.spec, 3.0, 4, 0)
        want = linear(s.Y.double().numpy(), s.mask.double().numpy())
        got = policy(s.Y.numpy(), s.mask.numpy())
        assert np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2)) < 0.1, path


def test_mixed_sizes_selection_rolls_out_every_size(tmp_path):
    paths, _ = _two_sizes(tmp_path)
    _, cfg = _config(tmp_path, training={'epochs': 1}, selection={'every': 1, 'trajectories': 1})
    trainer = Trainer(cfg, paths, str(tmp_path / 'run'), progress=False, log=lambda *a: None)
    seen = []
    with spy_on_selection_rollouts(lambda z0, steps, dt: seen.append(z0.shape)):
        trainer.run()
    assert seen == [(1, 5, 4), (1, 9, 4)]
    assert len(trainer.best['metrics']) and trainer.best['epoch'] == 1


def test_mixed_files_must_share_dt_and_multi_step_takes_one_file(tmp_path, capsys):
    paths, _ = _two_sizes(tmp_path)
    cfg_path, _ = _config(tmp_path)
    odd = tmp_path / 'odd.npz'
    from knode_swarm_ros.core import load_trajectories

    d = load_trajectories(paths[1])
    save_trajectories(odd, d.states, 0.02, 'flock2d', d.meta)
    assert (
        train_main(
            [
                '--config',
                cfg_path,
                '--data',
                paths[0],
                str(odd),
                '--out',
                str(tmp_path / 'r'),
                '--no-progress',
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert 'odd.npz' in err and "'dt'" in err and not os.path.exists(tmp_path / 'r' / 'policy.pt')
    raw = yaml.safe_load(open(cfg_path))
    raw['training'] = {'objective': 'multi_step', 'threads': 1}
    raw['multistep'] = {'horizons': [2], 'epochs': [1]}
    (tmp_path / 'ms.yaml').write_text(yaml.safe_dump(raw))
    assert (
        train_main(
            [
                '--config',
                str(tmp_path / 'ms.yaml'),
                '--data',
                *paths,
                '--out',
                str(tmp_path / 'm'),
                '--no-progress',
            ]
        )
        == 2
    )
    assert 'multi_step' in capsys.readouterr().err


def test_provenance_names_data_relative_to_the_repository_or_the_cwd(tmp_path, monkeypatch):
    root = tmp_path / 'repo'
    (root / 'data').mkdir(parents=True)
    (root / 'data' / 'x.npz').write_bytes(b'')
    assert data_reference(str(root / 'data' / 'x.npz'), root=str(root)) == 'data/x.npz'
    monkeypatch.chdir(root / 'data')
    assert data_reference('x.npz', root=str(root)) == 'data/x.npz'  # wherever it is run from
    outside = tmp_path / 'elsewhere' / 'y.npz'
    outside.parent.mkdir()
    monkeypatch.chdir(tmp_path)
    assert data_reference(str(outside), root=str(root)) == 'elsewhere/y.npz'


def test_trained_policy_provenance_is_relative_with_commit(tmp_path, monkeypatch):
    data, _ = _teacher_data(tmp_path)
    _, cfg = _config(tmp_path, selection={'every': 0}, training={'epochs': 1})
    monkeypatch.chdir(tmp_path)
    Trainer(cfg, 'teacher.npz', str(tmp_path / 'run'), progress=False, log=lambda *a: None).run()
    prov = load_policy(tmp_path / 'run' / 'policy.pt').meta['provenance']
    assert prov['data'] == 'teacher.npz' and not os.path.isabs(prov['data'])
    commit = prov['git_commit']
    assert commit is not None and len(commit.split('-')[0]) == 40
    assert prov['git_tree_clean'] == (not commit.endswith('-dirty'))


def test_provenance_rewrite_keeps_the_policy_and_its_twin(tmp_path, capsys):
    src = shipped_policy_path('flock2d_20hz')
    pt = tmp_path / 'p.pt'
    shutil.copy(src, pt)
    before = load_policy(pt)
    assert provenance_main([str(pt), '--data', 'data/flock2d.npz']) == 0
    after = load_policy(pt)
    assert after.meta['provenance']['data'] == 'data/flock2d.npz'
    assert after.meta['provenance']['git_commit'] == before.meta['provenance']['git_commit']
    assert 'metadata_rewritten_at' in after.meta['provenance']
    rest = {k: v for k, v in after.meta.items() if k != 'provenance'}
    assert rest == {k: v for k, v in before.meta.items() if k != 'provenance'}
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(16, before.k, 4)).astype(np.float32)
    mask = np.ones((16, before.k), np.float32)
    np.testing.assert_array_equal(after(Y, mask), before(Y, mask))
    twin = load_runtime(pt, 'onnxruntime')
    assert twin.meta == after.meta
    np.testing.assert_allclose(twin(Y, mask), after(Y, mask), atol=1e-5)
    assert provenance_main([str(tmp_path / 'missing.pt'), '--data', 'd.npz']) == 2
    assert 'missing.pt' in capsys.readouterr().err


def test_shipped_policies_name_their_data_relatively_and_a_commit():
    for name in ('flock2d', 'flock2d_20hz', 'boids3d', 'boids3d_unity'):
        prov = load_policy(shipped_policy_path(name)).meta['provenance']
        assert not os.path.isabs(prov['data']) and prov['data'].startswith('data/'), (name, prov['data'])
        assert len(prov['git_commit'].split('-')[0]) == 40, name
