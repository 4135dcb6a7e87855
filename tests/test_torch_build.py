"""The venv gets the CPU build of the pinned torch wherever it is installed,
or stops with a message that says how (tools/torch_build.py, run by `make venv`)."""

import importlib.util
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location('torch_build', REPO / 'tools' / 'torch_build.py')
torch_build = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(torch_build)

CPU = {
    'metadata': {'version': '2.13.0+cpu', 'requires_dist': ['filelock', 'sympy>=1.13.3']},
    'download_info': {'url': 'file:///opt/wheels/torch-2.13.0+cpu.whl'},
}
CUDA = {
    'metadata': {
        'version': '2.13.0',
        'requires_dist': ['filelock'] + [f'nvidia-lib{i}==1; platform_system == "Linux"' for i in range(16)],
    },
    'download_info': {'url': 'https://files.pythonhosted.org/torch-2.13.0-manylinux.whl'},
}
MAC = {
    'metadata': {'version': '2.13.0', 'requires_dist': ['filelock']},
    'download_info': {'url': 'https://files.pythonhosted.org/torch-2.13.0-macosx.whl'},
}


def fake_pip(default, cpu_index):
    calls = []

    def pip(args):
        calls.append(args)
        item = cpu_index if '--index-url' in args else default
        return (0, {'install': [item]}, '') if item is not None else (1, None, 'no matching distribution')

    return pip, calls


def test_the_pin_is_read_from_requirements():
    pin = torch_build.torch_pin()
    assert re.fullmatch(r'torch==\d+\.\d+\.\d+', pin)


@pytest.mark.parametrize(
    'item,cpu', [(CPU, True), (CUDA, False), (MAC, True), ({'metadata': {'version': '2.13.0+cu130'}}, False)]
)
def test_cpu_builds_are_told_from_cuda_builds(item, cpu):
    assert torch_build.is_cpu_build(item) is cpu


def test_the_configured_cpu_build_is_used_as_it_is():
    pip, calls = fake_pip(CPU, None)
    assert torch_build.choose('torch==2.13.0', pip) == ['install', '--no-deps', 'torch==2.13.0']
    assert len(calls) == 1 and '--dry-run' in calls[0] and '--no-deps' in calls[0]


def test_a_cuda_resolution_switches_to_the_cpu_index(capsys):
    pip, calls = fake_pip(CUDA, CPU)
    args = torch_build.choose('torch==2.13.0', pip, cpu_index='https://example.invalid/whl/cpu')
    assert args[-2:] == ['--index-url', 'https://example.invalid/whl/cpu'] and '--no-deps' in args
    assert 'requires 16 nvidia-* packages' in capsys.readouterr().out


def test_no_cpu_build_anywhere_stops_with_status_2_and_says_how(capsys):
    pip, _ = fake_pip(CUDA, None)
    with pytest.raises(SystemExit) as err:
        torch_build.choose('torch==2.13.0', pip)
    assert err.value.code == 2
    text = capsys.readouterr().err
    assert (
        'no CPU build of torch==2.13.0' in text
        and 'TORCH_BUILD=cuda' in text
        and 'download.pytorch.org' in text
    )


def test_cuda_is_an_explicit_opt_in(monkeypatch):
    monkeypatch.setenv('TORCH_BUILD', 'cuda')
    monkeypatch.setattr(
        torch_build, 'choose', lambda *a, **k: pytest.fail('no CPU check with TORCH_BUILD=cuda')
    )
    assert torch_build.main() == 0
    monkeypatch.setenv('TORCH_BUILD', 'rocm7')
    assert torch_build.main() == 2


def test_make_venv_runs_it_before_the_requirements():
    recipe = (REPO / 'Makefile').read_text()
    assert recipe.index('tools/torch_build.py\n') < recipe.index('pip install -r requirements-dev.txt')


def test_the_configured_sources_here_resolve_a_cpu_build():
    """On this machine the configured pip source has the CPU build (the path `make` takes)."""
    item = torch_build.resolve(torch_build.torch_pin())
    if item is None:
        pytest.skip('pip cannot resolve torch from the configured sources here (offline)')
    assert torch_build.is_cpu_build(item), torch_build.describe(item)
