"""Command lines a field user can type: an option's value may start with ``-``.

argparse reads ``--origin -35.36,149.16,584`` (a southern site) as two options and fails with
"expected one argument": only a plain negative number like ``-35.36`` passes as a value, and
only ``--origin=-35.36,...`` works for a coordinate list. :class:`ArgumentParser` joins such a
value to its option before argparse sees it, for every option that takes exactly one value
(``--origin``, ``--home``, ``--geo``, ``--to``...), in the parser and in its subcommands' parsers.

A token is joined only when it looks like a value, never like an option: a ``-`` followed by a
digit or a ``.`` (``-35.36,149.16``, ``-20``, ``-.5``). So ``--origin --fcu udpin:...`` still
says that ``--origin`` lacks its value, and a flag followed by a negative positional
(``mrswarm gcs goto --all -20 5 10``) stays as it is.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

_VALUE_LIKE = re.compile(r"^-[\d.]")


def join_dash_values(parser: argparse.ArgumentParser, argv: Sequence[str]) -> list[str]:
    """``argv`` with each value that starts with ``-`` joined to its option (``--origin=-35.36,...``).

    Only options of ``parser`` that take exactly one value are joined; everything after ``--``
    is left alone."""
    actions = parser._option_string_actions  # argparse's own table: option string -> action
    out: list[str] = []
    i = 0
    while i < len(argv):
        tok = argv[i]
        if tok == "--":
            out += argv[i:]
            break
        action = actions.get(tok)
        if (action is not None and action.nargs is None and tok.startswith("--") and i + 1 < len(argv)
                and _VALUE_LIKE.match(argv[i + 1]) and argv[i + 1][:2] not in actions):
            out.append(f"{tok}={argv[i + 1]}")
            i += 2
            continue
        out.append(tok)
        i += 1
    return out


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, except that an option's value may start with ``-`` (:func:`join_dash_values`),
    and a usage error is one line (``mrswarm agent: error: --fcu is required ...``, exit 2) rather
    than the whole usage block above it.

    Subcommands made with ``add_subparsers`` are of this class too, so each joins its own options."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def parse_known_args(self, args: Sequence[str] | None = None, namespace: Any = None) -> Any:  # type: ignore[override]
        argv = sys.argv[1:] if args is None else list(args)
        return super().parse_known_args(join_dash_values(self, argv), namespace)
