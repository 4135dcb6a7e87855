"""The one runner of every command-line main (docs/DESIGN.md, "Errors and exit statuses").

    @cli("python -m training.train")
    def main(argv=None) -> int:
        args = parser.parse_args(argv)   # argparse reports its own errors (exit 2)
        ...                              # raise KnodeError / RunError subclasses; return 0

:func:`cli` turns what escapes ``main`` into one line ``prog: error: <message>`` on stderr (no
traceback) and the exit status: :class:`~.errors.KnodeError`'s ``exit_status`` (2 bad input,
1 a failed run, 3 where a command documents it), 2 for a ``ValueError`` or ``OSError`` (the
standard library's and numpy's words for an unusable value or file: a missing or unreadable
input, an unparsable number), 130 for Ctrl-C. Anything else is a bug and keeps its traceback.
:func:`parse_set` is the shared ``--set SECTION.KEY=VALUE`` parser.
"""

import functools
import math
import sys
from typing import Any, Callable, Dict, Iterable, Optional

from .errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, ConfigError, KnodeError

__all__ = ['cli', 'report', 'parse_set']


def report(prog: str, exc: BaseException) -> int:
    """Print ``prog: error: <exc>`` on stderr; return the exit status ``exc`` stands for."""
    if isinstance(exc, KeyboardInterrupt):
        print(f'{prog}: interrupted', file=sys.stderr)
        return EXIT_INTERRUPTED
    if isinstance(exc, OSError) and not str(exc):
        exc = OSError(type(exc).__name__)
    print(f'{prog}: error: {exc}', file=sys.stderr)
    return exc.exit_status if isinstance(exc, KnodeError) else EXIT_BAD_INPUT


def cli(prog: str) -> Callable[[Callable[..., Optional[int]]], Callable[..., int]]:
    """Decorate a ``main(argv=None) -> int`` so that errors end as described in the module doc.

    ``SystemExit`` (argparse, ``parser.error``) passes through unchanged.
    """

    def wrap(main: Callable[..., Optional[int]]) -> Callable[..., int]:
        @functools.wraps(main)
        def run(*args: Any, **kwargs: Any) -> int:
            try:
                status = main(*args, **kwargs)
            except (KnodeError, ValueError, OSError, KeyboardInterrupt) as exc:
                return report(prog, exc)
            return 0 if status is None else int(status)

        run.prog = prog
        return run

    return wrap


def parse_set(items: Optional[Iterable[str]]) -> Dict[str, Any]:
    """``["training.epochs=10", ...]`` (repeated ``--set SECTION.KEY=VALUE``) -> ``{"training.epochs": 10}``,
    each value parsed as YAML (``10`` an int, ``[1, 2]`` a list, ``adjoint`` a string; ``1e-4`` a
    float, which YAML alone would read as a string).

    Raises:
        ConfigError: an item without ``=``, or a value that is not valid YAML.
    """
    import yaml

    from .yaml_file import load_yaml

    out: Dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition('=')
        if not sep or not key.strip():
            raise ConfigError(f'--set {item!r}: expected SECTION.KEY=VALUE')
        try:
            parsed = load_yaml(value)
        except yaml.YAMLError as exc:
            raise ConfigError(f'--set {item!r}: the value is not valid YAML ({exc})') from None
        out[key.strip()] = _number(parsed)
    return out


def _number(value: Any) -> Any:
    """YAML 1.1 reads ``1e-4`` (no dot) as text; a string that Python reads as a finite number is
    one (``inf``, ``nan`` and words stay text)."""
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            return value
        if math.isfinite(number) and any(c.isdigit() for c in value):
            return number
    return value
