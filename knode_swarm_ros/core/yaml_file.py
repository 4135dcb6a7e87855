"""Reading YAML from users (scenario, fleet and config files, ``--set`` values) with errors that
name the input.

:func:`load_yaml` is ``yaml.safe_load`` whose every failure on a hostile document is a
``yaml.YAMLError``: pyyaml's own constructors raise ``IndexError`` (``!!int`` with no digits),
``KeyError`` (``!!bool maybe``) or ``AttributeError`` (``!!timestamp soon``) on a tagged scalar
they cannot read, Python's int conversion a ``ValueError`` beyond 4300 digits, and its composer a
``RecursionError`` on nesting a few hundred levels deep.
"""

import inspect
from typing import Any, Type

from .errors import KnodeError

__all__ = ['load_yaml', 'read_yaml']

_LOADER = None


def _loader():
    """A SafeLoader whose scalar constructors raise ``ConstructorError`` on what they cannot read."""
    global _LOADER
    if _LOADER is None:
        import yaml
        from yaml.constructor import ConstructorError

        class Loader(yaml.SafeLoader):
            pass

        def checked(construct):
            def construct_or_refuse(loader, node):
                try:
                    return construct(loader, node)
                except (IndexError, KeyError, AttributeError, TypeError, ValueError, OverflowError) as exc:
                    raise ConstructorError(
                        None, None, f'cannot read {node.value!r} as {node.tag} ({exc!r})', node.start_mark
                    ) from None

            return construct_or_refuse

        for tag, construct in yaml.SafeLoader.yaml_constructors.items():
            if not inspect.isgeneratorfunction(construct):  # sequences and mappings: built in two steps
                Loader.add_constructor(tag, checked(construct))
        _LOADER = Loader
    return _LOADER


def load_yaml(stream) -> Any:
    """The document of ``stream`` (text or a file), as ``yaml.safe_load`` reads it.

    Raises:
        yaml.YAMLError: not valid YAML, a tagged scalar that is not of its tag, an integer of more
            than 4300 digits, or nesting too deep for the parser.
    """
    import yaml

    try:
        return yaml.load(stream, Loader=_loader())
    except RecursionError:
        raise yaml.YAMLError('nested too deeply') from None
    except ValueError as exc:  # a value's conversion outside a constructor (none known)
        raise yaml.YAMLError(str(exc)) from None


def read_yaml(path: str, error: Type[KnodeError], where: str) -> Any:
    """The document of the YAML file ``path``.

    Raises:
        error: ``'<where>: cannot be read (...)'`` or ``'<where>: not valid YAML (...)'``.
    """
    import yaml  # with the readers only: importing the core stays light

    try:
        with open(path, encoding='utf-8') as fh:
            return load_yaml(fh)
    except OSError as exc:
        raise error(f'{where}: cannot be read ({exc.strerror or exc})') from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise error(f'{where}: not valid YAML ({exc})') from None
