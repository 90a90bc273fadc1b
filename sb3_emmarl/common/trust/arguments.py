"""argparse pieces the command lines share (``emmarl train|enjoy|compare|benchmark|patrol``, the benchmarks): errors in
one line, rl-zoo's ``key:value`` pairs read as data, and JSON objects."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any, NoReturn

from sb3_emmarl.common.trust.safe_config import parse_value


def parse_key_values(items: list[str] | None, flag: str) -> dict[str, Any]:
    """rl-zoo's ``key:value`` pairs; values are Python literals read as data by
    :func:`~sb3_emmarl.common.trust.safe_config.parse_value` (quote strings: ``region:"'forest'"``), never evaluated.

    :param items: the ``key:value`` strings
    :param flag: the flag's name, for error messages
    :raise ValueError: naming the pair that does not parse
    """
    result: dict[str, Any] = {}
    for item in items or []:
        key, sep, value = item.partition(":")
        if not sep or not key:
            raise ValueError(f"{flag} expects key:value pairs, got {item[:80]!r}")
        result[key] = parse_value(value, f"{flag} {key}")
    return result


def json_object(text: str) -> dict[str, Any]:
    """An argparse ``type`` for a flag that takes a JSON object (``--env-kwargs '{"shaping": 0.5}'``): the dict, or the
    parser's error naming the value."""
    try:
        value = json.loads(text)
    except ValueError as error:  # (json's JSONDecodeError is one)
        raise argparse.ArgumentTypeError(f"not JSON ({error}): {text!r}") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"must be a JSON object, got {text!r}")
    return value


class KeyValues(argparse.Action):
    """argparse action storing ``key:value`` pairs as a dict (see :func:`parse_key_values`); a pair that does not
    parse is the parser's error."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: str | Sequence[Any] | None, option_string: str | None = None) -> None:
        items = [values] if isinstance(values, str) else list(values or [])
        try:
            setattr(namespace, self.dest, parse_key_values(items, option_string or self.dest))
        except ValueError as error:
            parser.error(str(error))


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line (``<prog>: error: <message> (--help for usage)``, exit code 2),
    without the usage block."""

    def error(self, message: str) -> NoReturn:
        """Exit with code 2 after one line naming the error.

        :param message: argparse's message
        """
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (--help for usage)\n")
