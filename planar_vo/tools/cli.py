"""What every ``planar_vo_*`` command line shares: one-line errors and argument types.

- :class:`Parser`: argparse whose usage error is one line on stderr,
  ``planar_vo_xxx: error: MESSAGE``, exit status 2 (no usage block, never a traceback).
- :func:`run`: the body of a command with the same one-line ending for what goes wrong after
  parsing (exit 2 for the command's own errors, 130 for Ctrl-C, 1 for a bug).
- Argument types (``type=``) whose refusal reads ``argument --x: must be ..., got ...``.
- :func:`add_topic_arguments`: the topic choices of the tools that run over a bag.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import NoReturn

__all__ = ['Parser', 'run', 'fail', 'integer', 'positive_int', 'non_negative_int',
           'int_range', 'finite_float', 'positive_float', 'non_negative_float', 'float_range',
           'add_topic_arguments']


class Parser(argparse.ArgumentParser):
    """argparse that reports a usage error in one line on stderr and exits 2."""

    def error(self, message: str) -> NoReturn:  # type: ignore[override]
        """``PROG: error: MESSAGE`` on stderr, exit status 2."""
        self.exit(2, f'{self.prog}: error: {message}\n')


def fail(prog: str, message: object) -> int:
    """Print ``PROG: error: MESSAGE`` on stderr; return exit status 2."""
    print(f'{prog}: error: {message}', file=sys.stderr)
    return 2


def run(prog: str, body: Callable[[], int], errors: tuple[type[BaseException], ...], *,
        internal: bool = False) -> int:
    """``body()``'s exit status, each way it can fail ending in one line on stderr.

    An exception of ``errors`` (what the user can fix: a missing bag, bad parameters) exits
    2, Ctrl-C 130; with ``internal``, any other exception exits 1 asking for a report
    instead of a traceback.
    """
    try:
        return body()
    except errors as err:
        return fail(prog, err)
    except KeyboardInterrupt:
        print(f'{prog}: interrupted', file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - a bug: one line, never a traceback
        if not internal:
            raise
        print(f'{prog}: internal error: {type(err).__name__}: {err} (please report this '
              'line)', file=sys.stderr)
        return 1


def _type(name: str, parse: Callable[[str], object]) -> Callable[[str], object]:
    parse.__name__ = name  # what argparse calls the type when it does not raise the message
    return parse


def integer(text: str) -> int:
    """An integer."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be an integer, got {text!r}') from None


def positive_int(text: str) -> int:
    """An integer > 0."""
    value = integer(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f'must be > 0, got {text}')
    return value


def non_negative_int(text: str) -> int:
    """An integer >= 0."""
    value = integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be non-negative, got {value}')
    return value


def int_range(low: int, high: int | None = None, why: str = '') -> Callable[[str], int]:
    """Type of an integer in ``[low, high]`` (``high`` None: no upper bound).

    ``why`` follows the lower bound in the message: ``must be at least 30 (why), got 10``.
    """
    def parse(text: str) -> int:
        value = integer(text)
        if high is None and value < low:
            raise argparse.ArgumentTypeError(
                f'must be at least {low}{f" ({why})" if why else ""}, got {value}')
        if high is not None and not low <= value <= high:
            raise argparse.ArgumentTypeError(f'must be {low} to {high}, got {value}')
        return value
    return _type('int_range', parse)  # type: ignore[return-value]


def _number(text: str, what: str = 'a number') -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be {what}, got {text!r}') from None


def finite_float(text: str) -> float:
    """A finite number."""
    value = _number(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be finite, got {text}')
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f'must be a finite number > 0, got {text}')
    return value


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f'must be a finite number >= 0, got {text}')
    return value


def float_range(low: float, high: float, unit: str) -> Callable[[str], float]:
    """Type of a number of ``unit`` in ``[low, high]``: ``must be 5 to 120 Hz, got 1``."""
    def parse(text: str) -> float:
        value = _number(text, f'a number of {unit}')
        if not low <= value <= high:  # NaN too
            raise argparse.ArgumentTypeError(f'must be {low:g} to {high:g} {unit}, got {text}')
        return value
    return _type('float_range', parse)  # type: ignore[return-value]


def add_topic_arguments(parser: argparse.ArgumentParser) -> None:
    """``--image-topic`` and ``--camera-info-topic``, for the tools that run over a bag."""
    parser.add_argument('--image-topic', help='image topic (default: the only one in the bag)')
    parser.add_argument('--camera-info-topic',
                        help='CameraInfo topic (default: the only one)')
