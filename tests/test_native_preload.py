"""nodes/native_preload: torch's native libraries load in a worker thread (GIL released), before
torch's own import, and torch works as usual afterwards (so a signal during start-up is
handled at once instead of after libtorch's dlopen)."""

import os
import subprocess
import sys

from knode_swarm_ros.nodes.common.native_preload import native_libraries

_CHECK = """
import sys
from knode_swarm_ros.nodes.common.native_preload import native_libraries, preload_native, preloading
libraries = native_libraries('torch')
assert [p for p, _ in libraries if '/_C.' in p] and [p for p, _ in libraries if 'global_deps' in p], libraries
def mapped():
    return {line.split()[-1].rsplit('/', 1)[-1] for line in open('/proc/self/maps') if '/torch/' in line}
assert not any(name.startswith('libtorch_cpu') for name in mapped())
if sys.argv[1] == 'direct':
    preload_native(['torch'])
    assert 'torch' not in sys.modules  # loaded, not imported
    assert any(name.startswith('libtorch_cpu') for name in mapped()), mapped()
    import torch
else:
    finders = list(sys.meta_path)
    with preloading():
        import torch
    assert sys.meta_path == finders
assert native_libraries('torch') == []  # imported: nothing left to preload
scripted = torch.jit.script(torch.nn.Linear(3, 2).double())
x = torch.ones(4, 3, dtype=torch.float64)
assert torch.equal(scripted(x), x @ scripted.weight.T + scripted.bias)
print('ok')
"""


def _run(how):
    return subprocess.run(
        [sys.executable, '-c', _CHECK, how], capture_output=True, text=True, timeout=300, env=dict(os.environ)
    )


def test_torch_libraries_load_before_its_import_and_torch_then_works():
    for how in ('direct', 'on_import'):
        proc = _run(how)
        assert proc.returncode == 0 and proc.stdout.strip() == 'ok', f'{how}\n{proc.stdout}\n{proc.stderr}'


def test_unknown_or_missing_packages_preload_nothing():
    assert native_libraries('numpy') == []  # not a known package
    assert native_libraries('no_such_package_knode') == []
