"""One error model for every command and node (docs/DESIGN.md, "Errors and exit statuses").

:class:`KnodeError` is the base of every error this project raises on purpose; each carries the
exit status a command-line program ends with when it escapes (:func:`knode_swarm_ros.core.cli.cli`
prints ``prog: error: <message>`` and exits with it):

* bad input (a file, field, argument or parameter; the message names it): :data:`EXIT_BAD_INPUT`;
  the domain subclasses (:class:`~.policy_meta.PolicyError`, :class:`~.trajectory.TrajectoryError`,
  :class:`ConfigError`, ``BagError``, ``DataError``, ``UnityFormatError``) are also ``ValueError``s,
  so that code catching ``ValueError`` catches them;
* :class:`RunError`: the input was fine but the run failed: :data:`EXIT_RUN_FAILED`, or a
  status a command documents (``training.train``'s divergence: 3).
"""

__all__ = [
    'EXIT_OK',
    'EXIT_RUN_FAILED',
    'EXIT_BAD_INPUT',
    'EXIT_INTERRUPTED',
    'KnodeError',
    'RunError',
    'ConfigError',
    'first_line',
]

EXIT_OK = 0
EXIT_RUN_FAILED = 1  # the input was fine, the run failed
EXIT_BAD_INPUT = 2  # refused: a bad argument, parameter, field or file (argparse's status too)
EXIT_INTERRUPTED = 130  # stopped by Ctrl-C / SIGTERM


class KnodeError(Exception):
    """Base of the project's errors: bad input unless a subclass says otherwise
    (``exit_status`` is what a command exits with when this escapes its main)."""

    exit_status = EXIT_BAD_INPUT


class RunError(KnodeError):
    """The input was accepted but the run failed (a process died, a run diverged, a timeout)."""

    exit_status = EXIT_RUN_FAILED


class ConfigError(KnodeError, ValueError):
    """A config field, parameter, argument or input file that prevents a command or node from
    starting; the message names it and the offending value. (The nodes and the training config
    share this one class: ``knode_swarm_ros.logic.common.ConfigError`` and
    ``training.learning.config.ConfigError`` are it.)"""


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (its type's name when the message is empty):
    what a one-line error names of a third-party failure."""
    text = str(exc).strip()
    return text.splitlines()[0].strip() if text else type(exc).__name__
