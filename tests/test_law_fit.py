"""``training.studies.law_fit``: the recipe's network regressed on a law's own commands."""

import re

from training.studies.law_fit import main


def _errors(capsys, *argv):
    assert main(['--law', 'aggregate2d', '--seconds', '1e9', *argv]) == 0
    out = capsys.readouterr().out
    signal, error = map(float, re.search(r'RMS ([0-9.]+), error RMS ([0-9.]+)', out).groups())
    bins = re.findall(r'nearest neighbour in \[.*\) m: (\d+) robots', out)
    return signal, error, out, sum(map(int, bins))


def test_fitting_lowers_the_error_on_held_out_states(capsys):
    signal, untrained, out, robots = _errors(capsys, '--epochs', '0')
    assert '0 epochs' in out and robots == 2 * 101 * 10  # every held-out robot in one bin
    _, fitted, out, _ = _errors(capsys, '--epochs', '3')
    assert '3 epochs' in out and 'encoder equivariant' in out  # the recipe's network
    assert fitted < 0.5 * untrained and fitted < signal


def test_recipe_fields_can_be_set(capsys):
    _, _, out, _ = _errors(capsys, '--epochs', '0', '--set', 'policy.encoder=set')
    assert 'encoder set, symmetric True' in out
    # values are YAML, as training.train's: a number is a number, not the string '0.5'
    _, _, out, _ = _errors(capsys, '--epochs', '0', '--set', 'policy.position_scale=0.5')
    assert 'position scale 0.5:' in out


def test_a_constant_speed_law_is_fitted_steered(capsys):
    # couzin2d moves at 1 m/s and turns at most 0.1 rad a step: the recipe derives both
    assert main(['--law', 'couzin2d', '--seconds', '1e9', '--epochs', '0']) == 0
    out = capsys.readouterr().out
    speed, limit = map(float, re.search(r'speed ([0-9.]+), turn limit ([0-9.]+)', out).groups())
    assert abs(speed - 1.0) < 1e-3 and abs(limit - 0.15) < 1e-3
    _, _, out, _ = _errors(capsys, '--epochs', '0')
    assert 'speed None, turn limit None' in out  # aggregate2d has no heading
