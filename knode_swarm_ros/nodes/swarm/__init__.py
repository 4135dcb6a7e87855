"""The ``swarm`` executable: a whole swarm on this machine, one OS process per node.

``swarm --scenario flock2d --robots 10 --steps 2000 --mode lockstep --record run.npz``

Starts the simulator, the recorder and one agent per robot (``python -m
knode_swarm_ros.nodes.<node> --ros-args ...``) on a fresh ROS_DOMAIN_ID with localhost-only
discovery, lets the simulator wait until every agent has heard every robot, runs, and stops every
process (SIGTERM, then SIGKILL) on completion, on Ctrl-C / SIGTERM, on a timeout, or when the
simulator or the recorder dies. An agent that dies is reported (which, and why) and the swarm goes
on without it (``--on-agent-exit stop`` stops instead); the exit status is then 3. Finally it
prints the metrics of the recording and draws a figure.

This launcher imports neither rclpy nor a message package: it is process management. Exit statuses:
0 done, 1 failed, 2 bad arguments or files, 3 done but an agent died, 130 interrupted.

The launcher's modules (none imports rclpy or a message package):

- :mod:`.cli`: the arguments and ``main``; - :mod:`.plan`: the checks, once, into a frozen
:class:`Plan` (the arguments are not changed); - :mod:`.commands`: a plan as command lines and
parameter files (:func:`build_commands` is pure); - :mod:`.processes`: one child process, its log,
stopping them; :mod:`.supervise`: the run (staged start, the watcher, the stop); - :mod:`.shm`:
FastDDS shared-memory cleanup; :mod:`.sweeper`: the process that cleans up after a killed
launcher; :mod:`.report`: the summary and the figure; - :mod:`.hosting`:
agents spread over processes and network namespaces.
"""

from ..common.startup import note_stop_signals, started_as_launcher

if started_as_launcher():  # before the imports below (a second or more): Ctrl-C is noted, no traceback
    note_stop_signals()

from .cli import build_parser, main
from .commands import PACKAGE, build_commands, child_environment, node_commands
from .plan import AGENT_MB, DOMAIN_RANGE, MAX_ROBOTS, NODE_MB, Plan, available_memory_mb, plan_run
from .processes import Child, Children, start_child
from .report import summarise, write_figure
from .shm import SHM_DIR, lock_held, shm_cleanup, shm_snapshot
from .supervise import run

__all__ = [
    'main',
    'build_parser',
    'plan_run',
    'Plan',
    'build_commands',
    'node_commands',
    'child_environment',
    'Child',
    'Children',
    'start_child',
    'run',
    'summarise',
    'write_figure',
    'shm_snapshot',
    'shm_cleanup',
    'lock_held',
    'SHM_DIR',
    'DOMAIN_RANGE',
    'MAX_ROBOTS',
    'AGENT_MB',
    'NODE_MB',
    'available_memory_mb',
    'PACKAGE',
]
