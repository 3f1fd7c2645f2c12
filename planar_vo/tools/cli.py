"""What every ``planar_vo_*`` command line shares: one-line errors and argument types.

- :class:`Parser`: argparse whose usage error is one line on stderr,
  ``planar_vo_xxx: error: MESSAGE``, exit status 2 (no usage block, never a traceback).
- :func:`run`: the body of a command with the same one-line ending for what goes wrong after
  parsing (exit 2 for the command's own errors, 130 for Ctrl-C, 1 for a bug).
- Argument types (``type=``) whose refusal reads ``argument --x: must be ..., got ...``.
- The arguments several tools share: the optional bag (the bundled one by default), the node's
  params file (the shipped one by default), the topics of the tools that run over a bag.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from planar_vo.io.resources import default_bag, default_params

__all__ = ['Parser', 'run', 'fail', 'integer', 'positive_int', 'non_negative_int',
           'int_range', 'finite_float', 'positive_float', 'non_negative_float', 'float_range',
           'number_list', 'add_bag_argument', 'add_node_params_argument', 'bag_or_default',
           'node_params_or_default', 'add_topic_arguments']


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


def integer(text: str) -> int:
    """An integer."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be an integer, got {text!r}') from None


def _number(text: str, what: str = 'a number') -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be {what}, got {text!r}') from None


def _checked(name: str, convert: Callable[[str], Any], ok: Callable[[Any], bool],
             requirement: str) -> Callable[[str], Any]:
    """Type converting with ``convert``; a value that is not ``ok`` reads ``must be ...``."""
    def parse(text: str) -> Any:
        value = convert(text)
        if not ok(value):
            raise argparse.ArgumentTypeError(f'must be {requirement}, got {text}')
        return value
    parse.__name__ = name  # what argparse calls the type when ``convert`` raises ValueError
    return parse


positive_int = _checked('positive_int', integer, lambda v: v > 0, '> 0')
non_negative_int = _checked('non_negative_int', integer, lambda v: v >= 0, 'non-negative')
finite_float = _checked('finite_float', _number, math.isfinite, 'finite')
positive_float = _checked('positive_float', _number, lambda v: math.isfinite(v) and v > 0,
                          'a finite number > 0')
non_negative_float = _checked('non_negative_float', _number,
                              lambda v: math.isfinite(v) and v >= 0, 'a finite number >= 0')


def int_range(low: int, high: int | None = None, why: str = '') -> Callable[[str], int]:
    """Type of an integer in ``[low, high]`` (``high`` None: no upper bound).

    ``why`` follows the lower bound in the message: ``must be at least 30 (why), got 10``.
    """
    if high is None:
        return _checked('int_range', integer, lambda v: v >= low,
                        f'at least {low}' + (f' ({why})' if why else ''))
    return _checked('int_range', integer, lambda v: low <= v <= high, f'{low} to {high}')


def float_range(low: float, high: float, unit: str) -> Callable[[str], float]:
    """Type of a number of ``unit`` in ``[low, high]``: ``must be 5 to 120 Hz, got 1``."""
    return _checked('float_range', lambda text: _number(text, f'a number of {unit}'),
                    lambda v: low <= v <= high, f'{low:g} to {high:g} {unit}')  # NaN too


def number_list(convert: Callable[[str], Any], kind: str, example: str,
                ok: Callable[[list], bool], requirement: str) -> Callable[[str], list]:
    """Type of a comma-separated list, e.g. ``number_list(int, 'integers', '1,2,3', ...)``."""
    def parse(text: str) -> list:
        try:
            values = [convert(part) for part in text.split(',')]
        except ValueError:
            raise argparse.ArgumentTypeError(
                f'must be comma-separated {kind} like {example}, got {text!r}') from None
        if not ok(values):
            raise argparse.ArgumentTypeError(f'must be {requirement}, got {text!r}')
        return values
    parse.__name__ = 'number_list'
    return parse


def add_bag_argument(parser: argparse.ArgumentParser, what: str = 'rosbag2 bag') -> None:
    """The optional bag positional of the tools that play the bundled bag without one."""
    parser.add_argument('bag', nargs='?', help=f'{what} (default: the bundled bags/default, '
                        'from the source tree or share/planar_vo)')


def add_node_params_argument(parser: argparse.ArgumentParser, flag: str = '--params',
                             when: str = '') -> None:
    """The params file given to planar_vo_node (default: the shipped one)."""
    parser.add_argument(flag, help=f'params YAML for the node{when} (default: the shipped '
                        'config/planar_vo.yaml)')


def bag_or_default(bag: str | None) -> Path:
    """The bag given, or the bundled one."""
    return Path(bag) if bag else default_bag()


def node_params_or_default(params: str | None) -> Path:
    """The params file given, or the shipped one."""
    return Path(params) if params else default_params()


def add_topic_arguments(parser: argparse.ArgumentParser) -> None:
    """``--image-topic`` and ``--camera-info-topic``, for the tools that run over a bag."""
    parser.add_argument('--image-topic', help='image topic (default: the only one in the bag)')
    parser.add_argument('--camera-info-topic',
                        help='CameraInfo topic (default: the only one)')
