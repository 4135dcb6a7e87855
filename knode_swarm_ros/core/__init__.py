"""The paper's maths, free of ROS: the one implementation everything else calls.

Public API (shapes: S swarms, T steps, n robots, d state entries, k rows, m command entries):

* scenarios: :class:`Scenario`, :func:`get_scenario` (``flock2d``, ``boids3d``).
* information network: :func:`neighbour_matrix` (``[..., n, d]`` -> ``Y [..., n, k, d]``,
  ``mask [..., n, k]``), :func:`neighbour_matrices` (whole trajectories with delay tau),
  :func:`neighbour_matrix_single` (one robot, for the agent node), :class:`DelayBuffer`.
* knowledge: :func:`collision_avoidance`, :func:`wall_avoidance`, :class:`AvoidanceGain`.
* policy: :class:`PolicyConfig`, :class:`KNODEPolicy` (``forward(Y [B, k, d], mask [B, k]) -> [B, m]``),
  :func:`export_policy`, :func:`load_policy`, :class:`LoadedPolicy`, :class:`PolicyError`,
  :func:`shipped_policy_path`.
* policy runtimes (torch-free unless TorchScript is chosen): :func:`load_runtime`
  (``auto | torchscript | onnxruntime``), :class:`OnnxPolicy` (the ONNX twin on onnxruntime),
  :func:`onnx_twin_path`.
* rollout: :func:`zoh_step`, :func:`rollout` (``[S, n, d]`` -> ``[S, T + 1, n, d]``).
* metrics: :func:`avd`, :func:`amd`, :func:`pod_energy`, :func:`pod_kld`.
* trajectory files: :func:`load_trajectories`, :func:`save_trajectories`, :class:`TrajectoryError`.
"""

import importlib
from typing import Any

# numpy-only parts are imported eagerly. (The function ``rollout`` must be bound here, after
# its submodule: importing a submodule sets the package attribute of the same name.)
from .delay_buffer import DelayBuffer
from .metrics import amd, avd, pod_energy, pod_kld
from .network import neighbour_matrices, neighbour_matrix, neighbour_matrix_rows, neighbour_matrix_single
from .policy_meta import PolicyError, shipped_policy_path
from .policy_runtime import RUNTIMES, OnnxPolicy, load_runtime, onnx_twin_path
from .rollout import rollout, zoh_step
from .scenarios import SCENARIOS, Scenario, ScenarioError, get_scenario, scenario_ref
from .trajectory import (
    TrajectoryError,
    TrajectoryFile,
    load_trajectories,
    parse_trajectory_ref,
    save_trajectories,
)

# The torch-based parts resolve lazily (PEP 562), so that numpy-only users (dataset
# generation, the simulator, the recorder) do not pay for importing torch.
_LAZY = {
    'knowledge': ['AvoidanceGain', 'collision_avoidance', 'wall_avoidance'],
    'policy': ['DEFAULTS', 'KNODEPolicy', 'PolicyConfig'],
    'policy_io': ['LoadedPolicy', 'export_policy', 'load_policy'],
}
_MODULE_OF = {name: module for module, names in _LAZY.items() for name in names}
__all__ = sorted(
    list(_MODULE_OF)
    + [
        'DelayBuffer',
        'amd',
        'avd',
        'pod_energy',
        'pod_kld',
        'neighbour_matrices',
        'neighbour_matrix',
        'neighbour_matrix_single',
        'neighbour_matrix_rows',
        'rollout',
        'zoh_step',
        'SCENARIOS',
        'Scenario',
        'ScenarioError',
        'get_scenario',
        'scenario_ref',
        'TrajectoryError',
        'TrajectoryFile',
        'load_trajectories',
        'parse_trajectory_ref',
        'save_trajectories',
        'PolicyError',
        'shipped_policy_path',
        'RUNTIMES',
        'OnnxPolicy',
        'load_runtime',
        'onnx_twin_path',
    ]
)


def __getattr__(name: str) -> Any:
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'.{module}', __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__
