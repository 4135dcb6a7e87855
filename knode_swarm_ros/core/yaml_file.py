"""Reading a user's YAML file (scenario, fleet) with errors that name the file."""

from typing import Any, Type

from .errors import KnodeError

__all__ = ['read_yaml']


def read_yaml(path: str, error: Type[KnodeError], where: str) -> Any:
    """The document of the YAML file ``path``.

    Raises:
        error: ``'<where>: cannot be read (...)'`` or ``'<where>: not valid YAML (...)'``.
    """
    import yaml  # with the readers only: importing the core stays light

    try:
        with open(path, encoding='utf-8') as fh:
            return yaml.safe_load(fh)
    except OSError as exc:
        raise error(f'{where}: cannot be read ({exc.strerror or exc})') from None
    except yaml.YAMLError as exc:
        raise error(f'{where}: not valid YAML ({exc})') from None
