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
* rollout: :func:`zoh_step`, :func:`rollout` (``[S, n, d]`` -> ``[S, T + 1, n, d]``).
* metrics: :func:`avd`, :func:`amd`, :func:`pod_energy`, :func:`pod_kld`.
* trajectory files: :func:`load_trajectories`, :func:`save_trajectories`, :class:`TrajectoryError`.
"""
from .delay_buffer import DelayBuffer
from .knowledge import AvoidanceGain, collision_avoidance, wall_avoidance
from .metrics import amd, avd, pod_energy, pod_kld
from .network import neighbour_matrices, neighbour_matrix, neighbour_matrix_single
from .policy import DEFAULTS, KNODEPolicy, PolicyConfig
from .policy_io import LoadedPolicy, PolicyError, export_policy, load_policy, shipped_policy_path
from .rollout import rollout, zoh_step
from .scenarios import SCENARIOS, Scenario, get_scenario
from .trajectory import (TrajectoryError, TrajectoryFile, load_trajectories, parse_trajectory_ref,
                         save_trajectories)

__all__ = ["DelayBuffer", "AvoidanceGain", "collision_avoidance", "wall_avoidance", "amd", "avd",
           "pod_energy", "pod_kld", "neighbour_matrices", "neighbour_matrix", "neighbour_matrix_single",
           "DEFAULTS", "KNODEPolicy", "PolicyConfig", "LoadedPolicy", "PolicyError", "export_policy",
           "load_policy", "shipped_policy_path", "rollout", "zoh_step", "SCENARIOS", "Scenario",
           "get_scenario", "TrajectoryError", "TrajectoryFile", "load_trajectories",
           "parse_trajectory_ref", "save_trajectories"]
